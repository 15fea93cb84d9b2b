//! The one exclusive prefix scan (shaders/scan.wgsl), reduce-then-scan in blocks of
//! `SCAN_BLOCK` values: `scan_reduce` writes each block's total, the next level scans those
//! totals (recursively), and `scan_blocks` scans each block from its scanned total. `WG_SCAN`
//! threads a block (a full workgroup on GPUs, one SIMD batch on CPUs) read their values straight
//! from the input, four at a time. The grid build scans its per-entry counts into the cell table
//! with it, the adaptive stage its flag bits. Integer adds only: exact, and the same on every
//! run. Mirror: `sim::reference::scan`.
use crate::error::Result;
use crate::gpu::buffers::{storage_zeroed, ParamSlots, Span};
use crate::gpu::live::LiveBuffer;
use crate::gpu::program::{entry_points, Dispatch, Program};
use crate::gpu::Context;

entry_points! {
    /// The entry points of shaders/scan.wgsl.
    enum ScanEntry in "scan.wgsl" {
        /// Each block's total, into the next level's input.
        Reduce = "scan_reduce",
        /// Each block's exclusive scan, offset by the next level's result.
        Blocks = "scan_blocks",
    }
}

/// Mirror of `ScanParams` in shaders/scan.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
struct ScanParams {
    n: u32,
    mask: u32,
    live_only: u32,
    offsets_on: u32,
}

/// What a scan counts at each position of its input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScanOf {
    /// The values themselves, all `max_len` of them.
    Values,
    /// 1 where `value & mask` is non-zero, for the live particles only (the rest count 0, and
    /// the output past the live count is left as it was).
    LiveFlags(u32),
}

struct Level {
    /// Workgroups of `scan_reduce` and `scan_blocks` (one per block of values).
    groups: u32,
    bind: wgpu::BindGroup,
}

/// An exclusive scan of the first `max_len` u32 of one input array into an output array (its
/// own, or a span the caller lends), in one or more modes ([`ScanOf`]) that share the buffers.
pub struct PrefixScan {
    program: Program<ScanEntry>,
    params: ParamSlots<ScanParams>,
    param_group: wgpu::BindGroup,
    levels: Vec<Level>,
    /// Scanned values of each level (level 0's is the result).
    outputs: Vec<Span>,
    /// Level 0's output is a span the caller lent.
    lent_output: bool,
    /// Block totals of each level, the next level's input (the last level's is bound but never
    /// written: a few bytes, so that every level binds the same layout).
    sums: Vec<wgpu::Buffer>,
    modes: usize,
}

impl PrefixScan {
    /// A scan of `input` into `output` (`max_len` u32 each; `None`: a buffer of its own). The
    /// input span must cover `max_len` rounded up to a multiple of 4 (the shader reads quads;
    /// what lies past `max_len` is not counted).
    pub fn new(
        ctx: &Context,
        input: &Span,
        output: Option<Span>,
        max_len: u32,
        live: &LiveBuffer,
        modes: &[ScanOf],
    ) -> Result<Self> {
        let program = Program::new(ctx)?;
        let block = crate::gpu::shaders::SCAN_BLOCK;
        // level k scans lens[k] values; its block totals are level k + 1's values
        let mut lens = vec![max_len.max(1)];
        while *lens.last().unwrap() > block {
            lens.push(lens.last().unwrap().div_ceil(block));
        }
        // the shader reads its input in quads
        let quads = |n: u32| n.next_multiple_of(4) as usize;
        assert!(
            input.size >= quads(max_len) as u64 * 4,
            "scan input span must cover whole quads"
        );
        let dev = &ctx.device;
        let own_output =
            |n: u32| Span::whole(&storage_zeroed::<u32>(dev, "scan output", n as usize));
        let mut outputs: Vec<Span> = lens.iter().map(|&n| own_output(n)).collect();
        let lent_output = output.is_some();
        if let Some(lent) = output {
            assert!(
                lent.size >= max_len as u64 * 4,
                "scan output span too short"
            );
            outputs[0] = lent;
        }
        let input = input.clone();
        let sums: Vec<wgpu::Buffer> = lens
            .iter()
            .map(|&n| storage_zeroed::<u32>(dev, "scan sums", quads(n.div_ceil(block))))
            .collect();
        let mut slots = Vec::new();
        for mode in modes {
            for (k, &n) in lens.iter().enumerate() {
                let (mask, live_only) = match mode {
                    ScanOf::LiveFlags(mask) if k == 0 => (*mask, 1),
                    _ => (0, 0),
                };
                slots.push(ScanParams {
                    n,
                    mask,
                    live_only,
                    offsets_on: (k + 1 < lens.len()) as u32,
                });
            }
        }
        let params = ParamSlots::new(ctx, "scan params", &slots);
        let mut levels = Vec::new();
        for (k, &len) in lens.iter().enumerate() {
            let src = if k == 0 {
                input.clone()
            } else {
                Span::whole(&sums[k - 1])
            };
            // the next level's output offsets the blocks; the last level has none (its
            // input stands in for the binding, unread)
            let offsets = outputs.get(k + 1).unwrap_or(&src);
            let own = [
                ("live", live.binding()),
                ("input", src.binding()),
                ("output", outputs[k].binding()),
                ("sums", sums[k].as_entire_binding()),
                ("offsets", offsets.binding()),
            ];
            levels.push(Level {
                groups: len.div_ceil(block),
                bind: program.bind(ctx, &[&own])?,
            });
        }
        // the per-dispatch parameters: group 1, a dynamic offset picks mode and level
        let param_group = program.bind_group(ctx, 1, &[&[("sp", params.slot(0))]])?;
        Ok(Self {
            program,
            params,
            param_group,
            levels,
            outputs,
            lent_output,
            sums,
            modes: modes.len(),
        })
    }

    /// The scan's result: `max_len` exclusive prefix sums.
    pub fn output(&self) -> &Span {
        &self.outputs[0]
    }

    /// Records the scan in mode `mode` (the index into the modes given to `new`).
    pub fn encode(&self, pass: &mut wgpu::ComputePass, mode: usize) {
        assert!(mode < self.modes, "scan mode {mode} of {}", self.modes);
        let group = &self.param_group;
        let slot = |k: usize| self.params.offset((mode * self.levels.len() + k) as u32);
        let last = self.levels.len() - 1;
        for (k, lv) in self.levels[..last].iter().enumerate() {
            self.program.dispatch(
                pass,
                ScanEntry::Reduce,
                &[(&lv.bind, 0), (group, slot(k))],
                Dispatch::Groups(lv.groups),
            );
        }
        for (k, lv) in self.levels.iter().enumerate().rev() {
            self.program.dispatch(
                pass,
                ScanEntry::Blocks,
                &[(&lv.bind, 0), (group, slot(k))],
                Dispatch::Groups(lv.groups),
            );
        }
    }

    /// Bytes the scan allocated (a lent output span is the lender's).
    pub fn device_bytes(&self) -> u64 {
        let own = self.outputs.iter().skip(self.lent_output as usize);
        own.map(|o| o.size).sum::<u64>()
            + self.sums.iter().map(|b| b.size()).sum::<u64>()
            + self.params.size()
    }
}
