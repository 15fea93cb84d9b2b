//! The GPU radix sort is a stable sort (equal keys keep input order) and matches its mirror.
use nimbus::config::GpuConfig;
use nimbus::gpu::sort::{key_bits, RadixSort};
use rand::{Rng, SeedableRng};

#[test]
fn radix_sort_is_a_stable_sort() {
    let ctx = nimbus::gpu::Context::new(&GpuConfig::default()).unwrap();
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    eprintln!("seed {seed}");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    for (n, max_key) in [
        (1usize, 5u32),
        (255, 3),
        (10_007, 1000),
        (70_001, (1 << 20) - 1),
    ] {
        let cap = n.next_multiple_of(64);
        let keys: Vec<u32> = (0..n).map(|_| rng.random_range(0..=max_key)).collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let mut init = vec![0u32; 4 * cap];
        init[..n].copy_from_slice(&keys);
        init[cap..cap + n].copy_from_slice(&vals);
        let buf = nimbus::gpu::buffers::storage_init(&ctx.device, "pairs", &init);
        let mut sort = RadixSort::new(&ctx.device, &buf, cap as u32, key_bits(max_key)).unwrap();
        sort.set_count(&ctx.queue, n as u32);
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            sort.encode(&mut pass);
        }
        ctx.queue.submit([enc.finish()]);
        let all: Vec<u32> =
            nimbus::gpu::buffers::read_back(&ctx.device, &ctx.queue, &buf, 4 * cap).unwrap();
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
