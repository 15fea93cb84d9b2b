//! The one exclusive prefix scan (shaders/scan.wgsl): blocks of `SCAN_BLOCK` values scanned in
//! workgroup memory by `WG_SCAN` threads (a full workgroup on GPUs, one SIMD batch on CPUs), the
//! block sums scanned recursively by the next level and added back. The grid build scans its
//! per-entry counts into the cell table with it, the adaptive stage its flag bits. Integer adds
//! only: exact, and the same on every run. Mirror: `sim::reference::scan`.
use crate::error::Result;
use crate::gpu::buffers::{storage_zeroed, ParamSlots, Span};
use crate::gpu::live::LiveBuffer;
use crate::gpu::stage::{Dispatch, Stage};
use crate::gpu::Context;

const SHADER: &str = "scan.wgsl";

/// Mirror of `ScanParams` in shaders/scan.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
struct ScanParams {
    n: u32,
    mask: u32,
    live_only: u32,
    _pad: u32,
}

/// What a scan counts at each position of its input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScanOf {
    /// The values themselves, all `max_len` of them.
    Values,
    /// 1 where `value & mask` is non-zero, for the live particles only (the rest count 0).
    LiveFlags(u32),
}

struct Level {
    /// Workgroups of `scan_blocks` and `scan_add` (one per block of values).
    groups: u32,
    blocks: wgpu::BindGroup,
    /// Adds the next level's scanned sums back (absent on the last level).
    add: Option<wgpu::BindGroup>,
}

/// An exclusive scan of the first `max_len` u32 of one input array into an output array (its
/// own, or a span the caller lends), in one or more modes ([`ScanOf`]) that share the buffers.
pub struct PrefixScan {
    stage: Stage,
    params: ParamSlots<ScanParams>,
    param_group: wgpu::BindGroup,
    levels: Vec<Level>,
    /// Scanned values of each level (level 0's is the result).
    outputs: Vec<Span>,
    /// Level 0's output is a span the caller lent.
    lent_output: bool,
    sums: Vec<wgpu::Buffer>,
    modes: usize,
}

impl PrefixScan {
    /// A scan of `input` into `output` (`max_len` u32 each; `None`: a buffer of its own).
    pub fn new(
        ctx: &Context,
        input: &Span,
        output: Option<Span>,
        max_len: u32,
        live: &LiveBuffer,
        modes: &[ScanOf],
    ) -> Result<Self> {
        let stage = Stage::new(ctx, SHADER, &["scan_blocks", "scan_add"])?;
        let block = crate::gpu::shaders::SCAN_BLOCK;
        // level k scans lens[k] values into lens[k].div_ceil(block) block sums
        let mut lens = vec![max_len.max(1)];
        while *lens.last().unwrap() > block {
            lens.push(lens.last().unwrap().div_ceil(block));
        }
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
            .map(|&n| storage_zeroed::<u32>(dev, "scan sums", n.div_ceil(block) as usize))
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
                    _pad: 0,
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
            // scan_blocks reads `input`; scan_add adds the next level's output back
            let level = |input: &Span| {
                let own = [
                    ("live", live.binding()),
                    ("input", input.binding()),
                    ("output", outputs[k].binding()),
                    ("sums", sums[k].as_entire_binding()),
                ];
                stage.bind(ctx, &[&own])
            };
            let blocks = level(&src)?;
            let add = outputs.get(k + 1).map(level).transpose()?;
            let groups = len.div_ceil(block);
            levels.push(Level {
                groups,
                blocks,
                add,
            });
        }
        // the per-dispatch parameters: group 1, a dynamic offset picks mode and level
        let param_group = stage.bind_group(ctx, 1, &[&[("sp", params.slot(0))]])?;
        Ok(Self {
            stage,
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
        for (k, lv) in self.levels.iter().enumerate() {
            self.stage.dispatch(
                pass,
                "scan_blocks",
                &[(&lv.blocks, 0), (group, slot(k))],
                Dispatch::Groups(lv.groups),
            );
        }
        for (k, lv) in self.levels.iter().enumerate().rev() {
            if let Some(add) = &lv.add {
                self.stage.dispatch(
                    pass,
                    "scan_add",
                    &[(add, 0), (group, slot(k))],
                    Dispatch::Groups(lv.groups),
                );
            }
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
