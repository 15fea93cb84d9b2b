//! Deterministic GPU sorting: a stable LSD radix sort of (key, value) u32 pairs, 4 bits per pass
//! (shaders/radix_sort.wgsl), ranked with the one prefix scan ([`crate::gpu::scan`]). Only
//! integer adds are involved, and ranks within a tile come from a prefix sum (not atomics), so
//! the output order is the same on every run and equal keys keep their input order. The number
//! of pairs is the live particle count, read on the GPU (`gpu::live`).
use crate::error::Result;
use crate::gpu::buffers::{range, storage_zeroed, ParamSlots, Span};
use crate::gpu::live::LiveBuffer;
use crate::gpu::scan::{PrefixScan, ScanOf};
use crate::gpu::stage::{Dispatch, Stage};
use crate::gpu::Context;

/// Mirror of `RadixParams` in shaders/radix_sort.wgsl.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RadixParams {
    shift: u32,
    num_tiles: u32,
    _p: [u32; 2],
}

/// Stable radix sort of the first `live.count` (key, value) pairs held in one buffer as four
/// u32 arrays of `capacity` entries: keys A, values A, keys B, values B (capacity a multiple of
/// 64 so each array starts on a 256-byte binding boundary). The input is read from A; the sorted
/// result is in A after an even number of passes and in B after an odd one (`result_offsets`).
pub struct RadixSort {
    stage: Stage,
    hist: wgpu::Buffer,
    params: ParamSlots<RadixParams>,
    param_group: wgpu::BindGroup,
    /// One bind group per pass (A -> B, B -> A alternately).
    binds: Vec<wgpu::BindGroup>,
    scan: PrefixScan,
    capacity: u32,
    max_tiles: u32,
}

impl RadixSort {
    pub fn new(
        ctx: &Context,
        pairs: &wgpu::Buffer,
        capacity: u32,
        key_bits: u32,
        live: &LiveBuffer,
    ) -> Result<Self> {
        assert!(
            capacity.is_multiple_of(64),
            "radix sort capacity must be a multiple of 64"
        );
        let stage = Stage::new(ctx, "radix_sort.wgsl", &["radix_count", "radix_scatter"])?;
        let passes = key_bits.max(1).div_ceil(4);
        let max_tiles = capacity.div_ceil(ctx.prelude.wg_block).max(1);
        let hist = storage_zeroed::<u32>(&ctx.device, "radix hist", (16 * max_tiles) as usize);
        let scan = PrefixScan::new(
            ctx,
            &Span::whole(&hist),
            None,
            16 * max_tiles,
            live,
            &[ScanOf::Values],
        )?;
        let params = ParamSlots::new(
            ctx,
            "radix params",
            &(0..passes)
                .map(|p| RadixParams {
                    shift: 4 * p,
                    num_tiles: max_tiles,
                    _p: [0; 2],
                })
                .collect::<Vec<_>>(),
        );
        let param_group = stage.bind_group(ctx, 1, &[&[("rp", params.slot(0))]])?;
        let arr = capacity as u64 * 4;
        let binds = (0..passes)
            .map(|p| {
                let (src, dst) = if p % 2 == 0 {
                    (0, 2 * arr)
                } else {
                    (2 * arr, 0)
                };
                let own = [
                    ("live", live.binding()),
                    ("keys_in", range(pairs, src, arr)),
                    ("vals_in", range(pairs, src + arr, arr)),
                    ("keys_out", range(pairs, dst, arr)),
                    ("vals_out", range(pairs, dst + arr, arr)),
                    ("hist", hist.as_entire_binding()),
                    ("offsets", scan.output().binding()),
                ];
                stage.bind(ctx, &[&own])
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            stage,
            hist,
            params,
            param_group,
            binds,
            scan,
            capacity,
            max_tiles,
        })
    }

    /// Records the sort of the live pairs.
    pub fn encode(&self, pass: &mut wgpu::ComputePass, live: &LiveBuffer) {
        for (p, bind) in self.binds.iter().enumerate() {
            let groups = [(bind, 0), (&self.param_group, self.params.offset(p as u32))];
            // every tile of the capacity: the histogram columns past the live count are zeroed
            self.stage.dispatch(
                pass,
                "radix_count",
                &groups,
                Dispatch::Groups(self.max_tiles),
            );
            self.scan.encode(pass, 0);
            self.stage
                .dispatch(pass, "radix_scatter", &groups, Dispatch::Live(live));
        }
    }

    /// Byte offsets of the sorted keys and values in the pairs buffer.
    pub fn result_offsets(&self) -> (u64, u64) {
        let arr = self.capacity as u64 * 4;
        if self.binds.len() % 2 == 1 {
            (2 * arr, 3 * arr)
        } else {
            (0, arr)
        }
    }

    pub fn device_bytes(&self) -> u64 {
        self.hist.size() + self.scan.device_bytes() + self.params.size()
    }
}

/// Bits needed to hold every key in `0..=max_key`.
pub fn key_bits(max_key: u32) -> u32 {
    32 - max_key.leading_zeros()
}
