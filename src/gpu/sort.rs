//! Deterministic GPU sorting: a multi-level exclusive prefix scan of u32 and a stable LSD radix
//! sort of (key, value) u32 pairs, 4 bits per pass (shaders/scan.wgsl, shaders/radix_sort.wgsl).
//! Only integer adds are involved, and ranks within a tile come from a prefix sum (not atomics),
//! so the output order is the same on every run and equal keys keep their input order.
use crate::error::Result;
use crate::gpu::buffers::{storage_zeroed, uniform_init};
use crate::gpu::kernel::{range, Bind, Kernel};

/// Elements per scan block and per radix tile (the workgroup size of both shaders).
pub const BLOCK: u32 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params4 {
    a: u32,
    b: u32,
    c: u32,
    d: u32,
}

struct ScanLevel {
    params: wgpu::Buffer,
    bind: wgpu::BindGroup,
    max_len: u32,
    len: u32,
}

/// Exclusive prefix sum over the first `n` u32 of a buffer, in place.
pub struct PrefixScan {
    kernel: Kernel,
    levels: Vec<ScanLevel>,
    sums: Vec<wgpu::Buffer>,
}

impl PrefixScan {
    pub fn new(device: &wgpu::Device, data: &wgpu::Buffer, max_len: u32) -> Result<Self> {
        let kernel = Kernel::new(
            device,
            "scan.wgsl",
            &[Bind::Uniform, Bind::Storage, Bind::Storage],
            &["scan_blocks", "scan_add"],
        )?;
        // level k scans `len_k` values into block sums of length ceil(len_k / BLOCK)
        let mut lens = vec![max_len.max(1)];
        while *lens.last().unwrap() > BLOCK {
            let l = lens.last().unwrap().div_ceil(BLOCK);
            lens.push(l);
        }
        let sums: Vec<wgpu::Buffer> = lens
            .iter()
            .map(|l| storage_zeroed::<u32>(device, "scan sums", l.div_ceil(BLOCK) as usize))
            .collect();
        let mut levels = Vec::new();
        for (k, &len) in lens.iter().enumerate() {
            let params = uniform_init(
                device,
                "scan params",
                &Params4 {
                    a: len,
                    b: 0,
                    c: 0,
                    d: 0,
                },
            );
            let src = if k == 0 { data } else { &sums[k - 1] };
            let bind = kernel.bind(
                device,
                &[
                    params.as_entire_binding(),
                    src.as_entire_binding(),
                    sums[k].as_entire_binding(),
                ],
            );
            levels.push(ScanLevel {
                params,
                bind,
                max_len: len,
                len,
            });
        }
        Ok(Self {
            kernel,
            levels,
            sums,
        })
    }

    /// Sets how many values the next `encode` scans (at most the `max_len` given at creation).
    pub fn set_len(&mut self, queue: &wgpu::Queue, n: u32) {
        let mut len = n.max(1);
        for lv in &mut self.levels {
            debug_assert!(len <= lv.max_len);
            lv.len = len;
            queue.write_buffer(
                &lv.params,
                0,
                bytemuck::bytes_of(&Params4 {
                    a: len,
                    b: 0,
                    c: 0,
                    d: 0,
                }),
            );
            len = len.div_ceil(BLOCK);
        }
    }

    pub fn encode(&self, pass: &mut wgpu::ComputePass) {
        for lv in &self.levels {
            self.kernel
                .dispatch(pass, "scan_blocks", &lv.bind, lv.len, BLOCK);
        }
        for lv in self.levels.iter().rev().skip(1) {
            self.kernel
                .dispatch(pass, "scan_add", &lv.bind, lv.len, BLOCK);
        }
    }

    pub fn device_bytes(&self) -> u64 {
        self.sums.iter().map(|b| b.size()).sum()
    }
}

/// Stable radix sort of `n` (key, value) pairs held in one buffer as four u32 arrays of
/// `capacity` entries: keys A, values A, keys B, values B (capacity a multiple of 64 so each
/// array starts on a 256-byte binding boundary). The input is read from A; the sorted result is
/// in A after an even number of passes and in B after an odd one (`result_in_b`).
pub struct RadixSort {
    kernel: Kernel,
    hist: wgpu::Buffer,
    params: Vec<wgpu::Buffer>,
    binds: Vec<wgpu::BindGroup>,
    scan: PrefixScan,
    capacity: u32,
    n: u32,
}

impl RadixSort {
    pub fn new(
        device: &wgpu::Device,
        pairs: &wgpu::Buffer,
        capacity: u32,
        key_bits: u32,
    ) -> Result<Self> {
        assert!(
            capacity.is_multiple_of(64),
            "radix sort capacity must be a multiple of 64"
        );
        let kernel = Kernel::new(
            device,
            "radix_sort.wgsl",
            &[
                Bind::Uniform,
                Bind::Storage,
                Bind::Storage,
                Bind::Storage,
                Bind::Storage,
                Bind::Storage,
            ],
            &["radix_count", "radix_scatter"],
        )?;
        let passes = key_bits.max(1).div_ceil(4);
        let max_tiles = capacity.div_ceil(BLOCK).max(1);
        let hist = storage_zeroed::<u32>(device, "radix hist", (16 * max_tiles) as usize);
        let scan = PrefixScan::new(device, &hist, 16 * max_tiles)?;
        let arr = capacity as u64 * 4;
        let mut params = Vec::new();
        let mut binds = Vec::new();
        for p in 0..passes {
            let pb = uniform_init(
                device,
                "radix params",
                &Params4 {
                    a: 0,
                    b: 4 * p,
                    c: 1,
                    d: 0,
                },
            );
            let (src, dst) = if p % 2 == 0 {
                (0, 2 * arr)
            } else {
                (2 * arr, 0)
            };
            binds.push(kernel.bind(
                device,
                &[
                    pb.as_entire_binding(),
                    range(pairs, src, arr),
                    range(pairs, src + arr, arr),
                    range(pairs, dst, arr),
                    range(pairs, dst + arr, arr),
                    hist.as_entire_binding(),
                ],
            ));
            params.push(pb);
        }
        Ok(Self {
            kernel,
            hist,
            params,
            binds,
            scan,
            capacity,
            n: 0,
        })
    }

    /// Number of pairs the next `encode` sorts.
    pub fn set_count(&mut self, queue: &wgpu::Queue, n: u32) {
        assert!(n <= self.capacity);
        self.n = n;
        let tiles = n.div_ceil(BLOCK).max(1);
        for (p, pb) in self.params.iter().enumerate() {
            let v = Params4 {
                a: n,
                b: 4 * p as u32,
                c: tiles,
                d: 0,
            };
            queue.write_buffer(pb, 0, bytemuck::bytes_of(&v));
        }
        self.scan.set_len(queue, 16 * tiles);
    }

    pub fn encode(&self, pass: &mut wgpu::ComputePass) {
        let threads = self.n.div_ceil(BLOCK).max(1) * BLOCK;
        for bg in &self.binds {
            self.kernel
                .dispatch(pass, "radix_count", bg, threads, BLOCK);
            self.scan.encode(pass);
            self.kernel
                .dispatch(pass, "radix_scatter", bg, threads, BLOCK);
        }
    }

    pub fn result_in_b(&self) -> bool {
        self.binds.len() % 2 == 1
    }

    /// Byte offsets of the sorted keys and values in the pairs buffer.
    pub fn result_offsets(&self) -> (u64, u64) {
        let arr = self.capacity as u64 * 4;
        if self.result_in_b() {
            (2 * arr, 3 * arr)
        } else {
            (0, arr)
        }
    }

    pub fn device_bytes(&self) -> u64 {
        self.hist.size() + self.scan.device_bytes()
    }
}

/// Bits needed to hold every key in `0..=max_key`.
pub fn key_bits(max_key: u32) -> u32 {
    32 - max_key.leading_zeros()
}
