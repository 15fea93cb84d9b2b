//! The grid build's counting sort is a stable sort by cell (equal keys keep input order) and
//! matches its mirror; the one prefix scan matches its mirror in both its modes (values, live
//! flag bits).
mod harness;

use nimbus::gpu::buffers::{read_back, storage_init, Span};
use nimbus::gpu::live::{Live, LiveBuffer};
use nimbus::gpu::scan::{PrefixScan, ScanOf};
use nimbus::gpu::shaders::{WG_SCAN_CPU, WG_SCAN_GPU};
use nimbus::gpu::Context;
use nimbus::ground::ParticleState;
use nimbus::sim::grid::GridStage;
use nimbus::sim::grid_params::GridParams;
use nimbus::sim::phase::Recorder;
use nimbus::sim::reference::grid::build_cell_table;
use rand::{Rng, SeedableRng};
use std::sync::Arc;

/// The grid build's counting sort is the stable sort by (cell, x slice) key of the mirror, with
/// its cell table: on a clump (hundreds of particles in one slice), one particle, a table larger
/// than an array of the pairs buffer (the counts' own buffer), and a walled, non-periodic box.
#[test]
fn the_grid_build_is_a_stable_sort_by_cell() {
    let ctx = harness::context();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(harness::fresh_seed());
    for (size, periodic, n, clump) in [
        ([8.0, 8.0, 8.0], true, 600usize, 500usize),
        ([8.0, 8.0, 8.0], true, 1, 0),
        ([40.0, 40.0, 40.0], true, 64, 0),
        ([12.0, 8.0, 12.0], false, 5000, 0),
    ] {
        let grid = GridParams::new(size, 2.0, periodic, periodic);
        let pos: Vec<[f32; 4]> = (0..n)
            .map(|i| {
                if i < clump {
                    // one x slice of one cell
                    [2.1, 3.1, 5.1].map(|c| c + rng.random_range(0.0..0.3f32))
                } else {
                    size.map(|s| rng.random_range(0.0..s as f32))
                }
            })
            .map(|p| [p[0], p[1], p[2], 0.0])
            .collect();
        let mut pos = pos;
        harness::off_cell_boundaries(&grid, &mut pos);
        let state = ParticleState {
            pos: pos.clone(),
            vel: vec![[0.0; 4]; n],
            thermo: vec![[290.0, 0.0, 0.0, 0.0]; n],
            info: (0..n as u32).map(|i| [i, 0]).collect(),
            density: vec![1.0; n],
        };
        let scene = harness::Scene::as_given(grid, state, n);
        let b = scene.upload(&ctx);
        // the keys are those of the predicted positions
        ctx.queue
            .write_buffer(&b.pred, 0, bytemuck::cast_slice(&pos));
        let stage = GridStage::new(&ctx, &grid, &b).unwrap();
        let (got, _) = harness::run_gpu(&ctx, &b, |rec, live| stage.build(rec, live));
        let p64: Vec<[f64; 3]> = pos.iter().map(harness::v3).collect();
        let (order, cell_start) = build_cell_table(&grid, &p64);
        let ids: Vec<u32> = got.info.iter().map(|i| i[0]).collect();
        assert_eq!(ids, order, "order, {n} particles in {size:?}");
        let want: Vec<[f32; 4]> = order.iter().map(|&o| pos[o as usize]).collect();
        assert_eq!(read_back::<[f32; 4]>(&ctx, &b.pred, n).unwrap(), want);
        let gpu_cs: Vec<u32> = read_back(&ctx, &b.cell_start, grid.table_len()).unwrap();
        assert_eq!(gpu_cs, cell_start, "cell table, {n} particles in {size:?}");
        // and the stable sort it stands for
        let mut stable: Vec<u32> = (0..n as u32).collect();
        stable.sort_by_key(|&i| grid.slice_key(p64[i as usize].into()));
        assert_eq!(order, stable);
    }
}

/// Both shapes of a scan block (2048 values either way): a full workgroup of threads, what GPUs
/// get, and one SIMD batch, what CPU devices get, whatever device runs the test.
#[test]
fn prefix_scan_matches_its_mirror_in_both_modes() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(harness::fresh_seed());
    for wg_scan in [WG_SCAN_GPU, WG_SCAN_CPU] {
        let mut ctx = Arc::into_inner(harness::context()).unwrap();
        ctx.prelude.wg_scan = wg_scan;
        scan_matches_mirror(&ctx, &mut rng);
    }
}

fn scan_matches_mirror(ctx: &Context, rng: &mut impl Rng) {
    let wg_scan = ctx.prelude.wg_scan;
    for (len, live_n) in [
        (1u32, 1u32),
        (256, 200),
        (257, 257),
        (2048, 2047),
        (2049, 2049),
        (70_000, 65_537),
        (300_000, 5),
        // three levels: more than 2048^2 values
        (4_200_000, 4_194_305),
    ] {
        let values: Vec<u32> = (0..len).map(|_| rng.random_range(0..16u32)).collect();
        // the input covers whole quads; what lies past `len` must not count
        let mut padded = values.clone();
        padded.resize(len.next_multiple_of(4) as usize, 15);
        let input = storage_init(&ctx.device, "scan input", &padded);
        let live = LiveBuffer::new(ctx, &Live::new(ctx, live_n, 0, true));
        let modes = [ScanOf::Values, ScanOf::LiveFlags(4)];
        let scan = PrefixScan::new(ctx, &Span::whole(&input), None, len, &live, &modes).unwrap();
        for (mode, what) in modes.iter().enumerate() {
            let mut rec = Recorder::new(ctx, None, None);
            scan.encode(&mut rec.pass(), mode);
            rec.submit();
            let got: Vec<u32> = read_back(ctx, &scan.output().buffer, len as usize).unwrap();
            let (n, mask) = match what {
                ScanOf::Values => (len as usize, 0),
                ScanOf::LiveFlags(m) => (live_n as usize, *m),
            };
            let want = nimbus::sim::reference::scan::exclusive_scan(&values, n, mask);
            assert_eq!(
                &got[..n],
                &want[..n],
                "{wg_scan} threads a block, len {len}, live {live_n}, {what:?}"
            );
        }
    }
}
