//! The GPU radix sort is a stable sort (equal keys keep input order) and matches its mirror; the
//! one prefix scan matches its mirror in both its modes (values, live flag bits).
mod harness;

use nimbus::gpu::buffers::{read_back, storage_init, Span};
use nimbus::gpu::live::{Live, LiveBuffer};
use nimbus::gpu::scan::{PrefixScan, ScanOf};
use nimbus::gpu::sort::{key_bits, RadixSort};
use nimbus::sim::phase::{Phase, Recorder};
use rand::{Rng, SeedableRng};

#[test]
fn radix_sort_is_a_stable_sort() {
    let ctx = harness::context();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(harness::fresh_seed());
    for (n, max_key, spare) in [
        (1usize, 5u32, 0usize),
        (255, 3, 700),
        (10_007, 1000, 64),
        (70_001, (1 << 20) - 1, 0),
    ] {
        // spare capacity: the histogram columns past the live count must not take part
        let cap = (n + spare).next_multiple_of(64);
        let keys: Vec<u32> = (0..n).map(|_| rng.random_range(0..=max_key)).collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let mut init = vec![0u32; 4 * cap];
        init[..n].copy_from_slice(&keys);
        init[cap..cap + n].copy_from_slice(&vals);
        // stale keys past the live count
        for k in init[n..cap].iter_mut() {
            *k = rng.random_range(0..=max_key);
        }
        let buf = storage_init(&ctx.device, "pairs", &init);
        let live = LiveBuffer::new(&ctx, &Live::new(&ctx, n as u32, 0, true));
        let sort = RadixSort::new(&ctx, &buf, cap as u32, key_bits(max_key), &live).unwrap();
        let mut rec = Recorder::new(&ctx, None, None);
        sort.encode(&mut rec.pass(Phase::Grid), &live);
        rec.submit();
        let all: Vec<u32> = read_back(&ctx, &buf, 4 * cap).unwrap();
        let (ko, vo) = sort.result_offsets();
        let gk = &all[ko as usize / 4..ko as usize / 4 + n];
        let gv = &all[vo as usize / 4..vo as usize / 4 + n];
        let mut expect = vals.clone();
        expect.sort_by_key(|&i| keys[i as usize]);
        assert_eq!(gv, &expect[..], "n = {n}");
        let (mk, mv) =
            nimbus::sim::reference::radix_sort::radix_sort(&keys, &vals, key_bits(max_key));
        assert_eq!(gk, &mk[..]);
        assert_eq!(gv, &mv[..]);
    }
}

#[test]
fn prefix_scan_matches_its_mirror_in_both_modes() {
    let ctx = harness::context();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(harness::fresh_seed());
    for (len, live_n) in [
        (1u32, 1u32),
        (256, 200),
        (257, 257),
        (70_000, 65_537),
        (300_000, 5),
    ] {
        let values: Vec<u32> = (0..len).map(|_| rng.random_range(0..16u32)).collect();
        let input = storage_init(&ctx.device, "scan input", &values);
        let live = LiveBuffer::new(&ctx, &Live::new(&ctx, live_n, 0, true));
        let modes = [ScanOf::Values, ScanOf::LiveFlags(4)];
        let scan = PrefixScan::new(&ctx, &Span::whole(&input), None, len, &live, &modes).unwrap();
        for (mode, what) in modes.iter().enumerate() {
            let mut rec = Recorder::new(&ctx, None, None);
            scan.encode(&mut rec.pass(Phase::Grid), mode);
            rec.submit();
            let got: Vec<u32> = read_back(&ctx, &scan.output().buffer, len as usize).unwrap();
            let (n, mask) = match what {
                ScanOf::Values => (len as usize, 0),
                ScanOf::LiveFlags(m) => (live_n as usize, *m),
            };
            let want = nimbus::sim::reference::scan::exclusive_scan(&values, n, mask);
            assert_eq!(&got[..n], &want[..n], "len {len}, live {live_n}, {what:?}");
        }
    }
}
