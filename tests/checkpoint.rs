//! Checkpoint format: bit-exact round trip, detection of every kind of damage, resume selection,
//! pruning, temporary-file cleanup, and failing disks (tmpfs that fills up, injected faults).
use nimbus::ground::ParticleState;
use nimbus::io::atomic::TMP_SUFFIX;
use nimbus::io::checkpoint::{self as ckpt, Checkpoint, CheckpointHeader, SkipReason};
use nimbus::Error;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

const HASH: &str = "5eed0123456789abcdef";

/// Random bits in every float (NaNs with payloads, infinities, subnormals, -0 included).
fn random_state(n: usize, rng: &mut ChaCha8Rng) -> ParticleState {
    let f = |rng: &mut ChaCha8Rng| {
        // Mix plain numbers with arbitrary bit patterns so both kinds are exercised.
        if rng.random_bool(0.5) {
            f32::from_bits(rng.random())
        } else {
            rng.random_range(-10.0f32..10.0)
        }
    };
    let f4 = |rng: &mut ChaCha8Rng| [f(rng), f(rng), f(rng), f(rng)];
    let mut s = ParticleState::default();
    for _ in 0..n {
        s.pos.push(f4(rng));
        s.vel.push(f4(rng));
        s.thermo.push(f4(rng));
        s.info.push([rng.random(), rng.random()]);
        s.density.push(f(rng));
    }
    // Specific payloads that a float round trip through arithmetic would lose.
    if n >= 2 {
        s.pos[0][0] = f32::from_bits(0x7fc0_1234);
        s.pos[0][1] = f32::from_bits(0xffa0_0001); // signalling NaN, negative
        s.vel[1][2] = -0.0;
        s.density[1] = f32::from_bits(1); // smallest subnormal
    }
    s
}

fn checkpoint(frame: u32, n: usize, seed: u64) -> Checkpoint {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let state = random_state(n, &mut rng);
    let mut extra = BTreeMap::new();
    extra.insert("adaptive".to_string(), (0..37u8).collect::<Vec<u8>>());
    extra.insert("empty".to_string(), Vec::new());
    Checkpoint {
        header: CheckpointHeader {
            tool_version: nimbus::VERSION.to_string(),
            sim_hash: HASH.to_string(),
            frame,
            step: 4 * frame as u64 + 3,
            time: frame as f64 / 24.0 + 1e-13,
            seed,
            particle_count: n as u64,
            capacity: 2 * n as u64 + 5,
            adapter: "llvmpipe (LLVM 19.1.7, 256 bits) (Vulkan)".to_string(),
            next_id: n as u32 + 11,
        },
        state,
        extra,
    }
}

fn bits4(v: &[[f32; 4]]) -> Vec<[u32; 4]> {
    v.iter().map(|a| a.map(f32::to_bits)).collect()
}

/// Bitwise equality (`PartialEq` on floats says NaN != NaN).
fn assert_bit_identical(a: &Checkpoint, b: &Checkpoint) {
    let (ha, hb) = (&a.header, &b.header);
    assert_eq!(ha.time.to_bits(), hb.time.to_bits());
    let mut ha2 = ha.clone();
    ha2.time = hb.time;
    assert_eq!(&ha2, hb);
    assert_eq!(bits4(&a.state.pos), bits4(&b.state.pos));
    assert_eq!(bits4(&a.state.vel), bits4(&b.state.vel));
    assert_eq!(bits4(&a.state.thermo), bits4(&b.state.thermo));
    assert_eq!(a.state.info, b.state.info);
    let d = |s: &ParticleState| s.density.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(d(&a.state), d(&b.state));
    assert_eq!(a.extra, b.extra);
}

/// The one-line reason of an `InvalidInput`, failing the test on anything else.
fn reason(r: nimbus::Result<Checkpoint>) -> String {
    match r {
        Err(e @ Error::InvalidInput(_)) => {
            assert_eq!(e.exit_code(), 2);
            let s = e.to_string();
            assert!(!s.contains('\n'), "reason is not one line: {s}");
            s
        }
        Err(e) => panic!("expected InvalidInput, got {e:?}"),
        Ok(_) => panic!("damaged checkpoint accepted"),
    }
}

fn written(dir: &Path, ck: &Checkpoint) -> (PathBuf, Vec<u8>) {
    let p = ckpt::write_checkpoint(dir, ck).unwrap();
    let b = fs::read(&p).unwrap();
    (p, b)
}

/// Recomputes the header crc and the trailing SHA-256 after a deliberate edit, so a test can
/// build a file whose checksums are right but whose content is hostile.
fn reseal(bytes: &mut [u8]) {
    use sha2::{Digest, Sha256};
    let hlen = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let hend = 16 + hlen;
    let crc = crc32fast::hash(&bytes[..hend]);
    bytes[hend..hend + 4].copy_from_slice(&crc.to_le_bytes());
    let n = bytes.len();
    let sha = Sha256::digest(&bytes[..n - 32]);
    bytes[n - 32..].copy_from_slice(sha.as_slice());
}

fn tmp_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.to_string_lossy().ends_with(TMP_SUFFIX) {
            out.push(p);
        }
    }
    out
}

#[test]
fn round_trip_is_bit_exact() {
    let dir = tempfile::tempdir().unwrap();
    for (frame, n) in [(0u32, 0usize), (7, 1), (12, 1000), (1_234_567, 33)] {
        let ck = checkpoint(frame, n, frame as u64 + 1);
        let p = ckpt::write_checkpoint(dir.path(), &ck).unwrap();
        assert_eq!(
            p.file_name().unwrap().to_str().unwrap(),
            ckpt::file_name(frame)
        );
        let back = ckpt::read_checkpoint(&p).unwrap();
        assert_bit_identical(&ck, &back);
        // Writing what was read gives the same bytes: nothing is normalised on the way.
        let again = tempfile::tempdir().unwrap();
        let p2 = ckpt::write_checkpoint(again.path(), &back).unwrap();
        assert_eq!(fs::read(&p).unwrap(), fs::read(&p2).unwrap());
    }
    assert_eq!(ckpt::file_name(12), "ckpt_000012.nck");
    assert_eq!(ckpt::frame_of_name("ckpt_000012.nck"), Some(12));
    assert_eq!(ckpt::frame_of_name("ckpt_1234567.nck"), Some(1_234_567));
    for bad in [
        "ckpt_.nck",
        "ckpt_12.nck.nimbus-tmp",
        "ckpt_1x.nck",
        "frame_000001.vdb",
    ] {
        assert_eq!(ckpt::frame_of_name(bad), None, "{bad}");
    }
    assert!(dir.path().read_dir().unwrap().all(|e| !e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .ends_with(TMP_SUFFIX)));
}

#[test]
fn size_is_sixty_bytes_per_particle_plus_fixed_overhead() {
    let dir = tempfile::tempdir().unwrap();
    let (_, small) = written(dir.path(), &checkpoint(1, 100, 1));
    let (_, large) = written(dir.path(), &checkpoint(2, 1100, 1));
    assert_eq!(large.len() - small.len(), 1000 * 60);
}

#[test]
fn truncation_at_every_cut_point_is_detected() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = written(dir.path(), &checkpoint(3, 20, 9));
    for cut in 0..bytes.len() {
        let r = ckpt::decode(&bytes[..cut]).map(|_| ()).unwrap_err();
        if cut == 0 {
            assert!(r.contains("empty"), "cut {cut}: {r}");
        } else {
            assert!(r.contains("truncated"), "cut {cut}: {r}");
        }
    }
    // Through the file API, on a larger file, at a spread of cut points.
    let (_, big) = written(dir.path(), &checkpoint(4, 5000, 9));
    let p = dir.path().join("cut.nck");
    for k in 0..40 {
        let cut = (big.len() as u64 * k / 40) as usize + k as usize;
        fs::write(&p, &big[..cut.min(big.len() - 1)]).unwrap();
        let r = reason(ckpt::read_checkpoint(&p));
        assert!(r.starts_with(&format!("{}: ", p.display())), "{r}");
        assert!(r.contains("truncated") || r.contains("empty"), "{r}");
    }
}

#[test]
fn every_single_bit_flip_is_detected() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = written(dir.path(), &checkpoint(5, 6, 2));
    for i in 0..bytes.len() {
        let mut b = bytes.clone();
        b[i] ^= 1 << (i % 8);
        let r = ckpt::decode(&b).map(|_| ()).unwrap_err();
        assert!(!r.is_empty() && !r.contains('\n'), "byte {i}: {r}");
    }
    // Random multi-bit damage in a larger file, through the file API.
    let (_, big) = written(dir.path(), &checkpoint(6, 3000, 2));
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let p = dir.path().join("flipped.nck");
    for _ in 0..60 {
        let mut b = big.clone();
        for _ in 0..rng.random_range(1..4) {
            let i = rng.random_range(0..b.len());
            b[i] ^= 1 << rng.random_range(0..8);
        }
        if b == big {
            continue;
        }
        fs::write(&p, &b).unwrap();
        reason(ckpt::read_checkpoint(&p));
    }
}

#[test]
fn damage_in_a_section_names_the_section() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = written(dir.path(), &checkpoint(5, 100, 2));
    // Header ~150 bytes, then 'pos' and 'vel' of 1600 data bytes each: byte 2500 is in 'vel'.
    let mut b = bytes.clone();
    let mid = 100 + 1600 + 800;
    b[mid] ^= 0x10;
    let r = ckpt::decode(&b).map(|_| ()).unwrap_err();
    assert!(r.contains("section 'vel' checksum mismatch"), "{r}");
    // The trailer itself.
    let mut b = bytes.clone();
    let n = b.len();
    b[n - 1] ^= 1;
    let r = ckpt::decode(&b).map(|_| ()).unwrap_err();
    assert!(r.contains("file checksum"), "{r}");
}

#[test]
fn wrong_magic_foreign_and_empty_files_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.nck");
    let cases: [(&[u8], &str); 6] = [
        (b"", "empty file"),
        (
            b" BDV\x00\x00\x00\x00\xdb\x00\x00\x00more",
            "not a nimbus checkpoint",
        ),
        (b"{\"frames\": []}\n", "not a nimbus checkpoint"),
        (b"NIMBUSCX\x01\x00\x00\x00", "not a nimbus checkpoint"),
        (b"X", "not a nimbus checkpoint"),
        (b"NIMB", "truncated"),
    ];
    for (content, want) in cases {
        fs::write(&p, content).unwrap();
        let r = reason(ckpt::read_checkpoint(&p));
        assert!(r.contains(want), "{content:?}: {r}");
        assert_eq!(
            ckpt::is_checkpoint(content),
            content.starts_with(b"NIMBUSCK")
        );
    }
    let (_, good) = written(dir.path(), &checkpoint(1, 3, 1));
    let mut b = good.clone();
    b[0] = b'n';
    fs::write(&p, &b).unwrap();
    assert!(reason(ckpt::read_checkpoint(&p)).contains("not a nimbus checkpoint"));
    assert!(ckpt::is_checkpoint(&good[..8]));
    assert!(!ckpt::is_checkpoint(&good[..7]));
}

#[test]
fn wrong_version_is_rejected_with_the_version() {
    let dir = tempfile::tempdir().unwrap();
    let (p, mut b) = written(dir.path(), &checkpoint(1, 3, 1));
    for v in [0u32, 2, 99] {
        b[8..12].copy_from_slice(&v.to_le_bytes());
        reseal(&mut b);
        fs::write(&p, &b).unwrap();
        let r = reason(ckpt::read_checkpoint(&p));
        assert!(r.contains(&format!("format version {v}")), "{r}");
    }
}

#[test]
fn hostile_lengths_neither_panic_nor_allocate() {
    let dir = tempfile::tempdir().unwrap();
    let (_, good) = written(dir.path(), &checkpoint(1, 10, 1));
    let hlen = u32::from_le_bytes(good[12..16].try_into().unwrap()) as usize;
    let sections_at = 16 + hlen + 4;
    // Section data length of u64::MAX, with every checksum recomputed.
    let mut b = good.clone();
    let len_at = sections_at + 2 + 3; // u16 name length, "pos"
    b[len_at..len_at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
    reseal(&mut b);
    let r = ckpt::decode(&b).map(|_| ()).unwrap_err();
    assert!(r.contains("more than the file holds"), "{r}");
    // A header that claims billions of particles (capacity too), checksums recomputed: the
    // section sizes are checked against it before anything is allocated.
    let mut b = good.clone();
    let body = &good[16..16 + hlen];
    let count_off = 16 + find(body, &10u64.to_le_bytes()); // particle count field
    b[count_off..count_off + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
    b[count_off + 8..count_off + 16].copy_from_slice(&(1u64 << 41).to_le_bytes());
    reseal(&mut b);
    let r = ckpt::decode(&b).map(|_| ()).unwrap_err();
    assert!(r.contains("section 'pos' has 160 bytes"), "{r}");
    // Header length beyond the limit, and one beyond the file.
    for hl in [u32::MAX, 60_000] {
        let mut b = good.clone();
        b[12..16].copy_from_slice(&hl.to_le_bytes());
        let r = ckpt::decode(&b).map(|_| ()).unwrap_err();
        assert!(r.contains("header"), "{r}");
    }
    // Trailing bytes after a complete file.
    let mut b = good.clone();
    b.extend_from_slice(b"junk");
    let r = ckpt::decode(&b).map(|_| ()).unwrap_err();
    assert!(r.contains("4 unexpected bytes"), "{r}");
}

fn find(hay: &[u8], needle: &[u8]) -> usize {
    hay.windows(needle.len())
        .position(|w| w == needle)
        .expect("field present")
}

#[test]
fn find_resumable_falls_back_to_the_newest_good_one() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut paths = Vec::new();
    for f in [10u32, 20, 30, 40] {
        paths.push(written(d, &checkpoint(f, 50, f as u64)).0);
    }
    // 40 bit-flipped, 30 truncated, a misnamed copy of 10 pretending to be 50, a temp file
    // and an unrelated file; 20 is the one to resume from.
    let mut b = fs::read(&paths[3]).unwrap();
    b[500] ^= 4;
    fs::write(&paths[3], &b).unwrap();
    let b = fs::read(&paths[2]).unwrap();
    fs::write(&paths[2], &b[..b.len() / 2]).unwrap();
    fs::copy(&paths[0], d.join("ckpt_000050.nck")).unwrap();
    fs::write(d.join(format!("ckpt_000060.nck{TMP_SUFFIX}")), b"half").unwrap();
    fs::write(d.join("notes.txt"), b"hi").unwrap();

    let (found, skipped) = ckpt::find_resumable(d, HASH).unwrap();
    let (p, ck) = found.expect("a good checkpoint");
    assert_eq!(p, paths[1]);
    assert_bit_identical(&ck, &checkpoint(20, 50, 20));
    assert_eq!(skipped.len(), 3, "{skipped:#?}");
    assert!(skipped[0].contains("ckpt_000050.nck") && skipped[0].contains("frame 50"));
    assert!(skipped[1].contains("ckpt_000040.nck") && skipped[1].contains("checksum"));
    assert!(skipped[2].contains("ckpt_000030.nck") && skipped[2].contains("truncated"));
    for s in &skipped {
        assert!(s.starts_with("skipping ") && !s.contains('\n'), "{s}");
    }
}

#[test]
fn find_resumable_reports_none_usable() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Missing and empty directories: nothing, no reasons.
    let (f, s) = ckpt::find_resumable(&d.join("missing"), HASH).unwrap();
    assert!(f.is_none() && s.is_empty());
    let (f, s) = ckpt::find_resumable(d, HASH).unwrap();
    assert!(f.is_none() && s.is_empty());
    fs::write(d.join("ckpt_000001.nck"), b"").unwrap();
    fs::write(d.join("ckpt_000002.nck"), b"garbage that is not ours").unwrap();
    let (p, _) = written(d, &checkpoint(3, 5, 1));
    let mut b = fs::read(&p).unwrap();
    b[8] = 7;
    fs::write(&p, &b).unwrap();
    let (f, s) = ckpt::find_resumable(d, HASH).unwrap();
    assert!(f.is_none());
    assert_eq!(s.len(), 3, "{s:#?}");
    assert!(s[0].contains("ckpt_000003.nck") && s[0].contains("format version 7"));
    assert!(s[1].contains("ckpt_000002.nck") && s[1].contains("not a nimbus checkpoint"));
    assert!(s[2].contains("ckpt_000001.nck") && s[2].contains("empty file"));
}

#[test]
fn config_mismatch_is_reported_distinctly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    written(d, &checkpoint(1, 5, 1));
    let mut other = checkpoint(2, 5, 1);
    other.header.sim_hash = "ffff".into();
    written(d, &other);
    let scan = ckpt::scan_resumable(d, HASH).unwrap();
    assert_eq!(scan.found.as_ref().unwrap().1.header.frame, 1);
    assert!(scan.config_changed());
    assert_eq!(
        scan.skipped[0].reason,
        SkipReason::ConfigMismatch {
            found: "ffff".into(),
            expected: HASH.into()
        }
    );
    assert!(scan.skipped[0]
        .to_string()
        .contains("simulation config changed"));
    // With another expected hash, frame 2 is the one, and nothing is skipped.
    let scan = ckpt::scan_resumable(d, "ffff").unwrap();
    assert_eq!(scan.found.unwrap().1.header.frame, 2);
    assert!(scan.skipped.is_empty() && !ckpt::scan_resumable(d, "ffff").unwrap().config_changed());
    // No match at all: none, both reported as mismatches.
    let scan = ckpt::scan_resumable(d, "0000").unwrap();
    assert!(scan.found.is_none() && scan.skipped.len() == 2 && scan.config_changed());
}

#[test]
fn prune_keeps_the_newest_k() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for f in 1..=6u32 {
        written(d, &checkpoint(f, 2, 1));
    }
    fs::write(d.join("keep.txt"), b"x").unwrap();
    let deleted = ckpt::prune(d, 3).unwrap();
    assert_eq!(deleted.len(), 3);
    let frames: Vec<u32> = ckpt::list_checkpoints(d)
        .unwrap()
        .into_iter()
        .map(|(f, _)| f)
        .collect();
    assert_eq!(frames, [4, 5, 6]);
    assert!(d.join("keep.txt").exists());
    // keep = 0 still keeps the newest.
    ckpt::prune(d, 0).unwrap();
    assert_eq!(ckpt::list_checkpoints(d).unwrap().len(), 1);
    assert!(d.join(ckpt::file_name(6)).exists());
}

#[test]
fn write_and_prune_never_deletes_the_one_just_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for f in [10u32, 20, 30] {
        ckpt::write_and_prune(d, &checkpoint(f, 2, 1), 2).unwrap();
    }
    let frames = |d: &Path| -> Vec<u32> {
        ckpt::list_checkpoints(d)
            .unwrap()
            .into_iter()
            .map(|(f, _)| f)
            .collect()
    };
    assert_eq!(frames(d), [20, 30]);
    // Resumed from 20 (30 was bad): writing 21 with keep 1 keeps 21, drops the stale 30.
    let p = ckpt::write_and_prune(d, &checkpoint(21, 2, 1), 1).unwrap();
    assert_eq!(frames(d), [21]);
    assert!(p.exists());
}

#[test]
fn remove_temp_files_cleans_the_whole_run_dir() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fs::create_dir_all(d.join("checkpoints")).unwrap();
    fs::create_dir_all(d.join("vdb/deep")).unwrap();
    let tmps = [
        d.join(format!("manifest.json{TMP_SUFFIX}")),
        d.join(format!("checkpoints/ckpt_000003.nck{TMP_SUFFIX}")),
        d.join(format!("vdb/deep/f_0001.vdb{TMP_SUFFIX}")),
    ];
    let keep = [
        d.join("manifest.json"),
        d.join("checkpoints/ckpt_000002.nck"),
        d.join("vdb/deep/f_0001.vdb"),
        d.join("vdb/nimbus-tmp.txt"),
    ];
    for p in tmps.iter().chain(&keep) {
        fs::write(p, b"data").unwrap();
    }
    let mut removed = nimbus::io::atomic::remove_temp_files(d).unwrap();
    removed.sort();
    let mut want = tmps.to_vec();
    want.sort();
    assert_eq!(removed, want);
    assert!(tmps.iter().all(|p| !p.exists()));
    assert!(keep.iter().all(|p| p.exists()));
    assert!(nimbus::io::atomic::remove_temp_files(d).unwrap().is_empty());
    assert!(nimbus::io::atomic::remove_temp_files(&d.join("missing"))
        .unwrap()
        .is_empty());
}

#[test]
fn describe_prints_the_header() {
    let dir = tempfile::tempdir().unwrap();
    let (p, mut b) = written(dir.path(), &checkpoint(42, 7, 3));
    let text = nimbus::io::inspect::describe(&p).unwrap();
    for want in [
        "frame            42",
        "step             171",
        "particles        7",
        "capacity         19",
        "seed             3",
        "next id          18",
        HASH,
        "llvmpipe",
        nimbus::VERSION,
        "adaptive (37 B)",
        "checksums        ok",
    ] {
        assert!(text.contains(want), "missing {want:?} in\n{text}");
    }
    let h = ckpt::read_header(&p).unwrap();
    assert_eq!(h.frame, 42);
    let n = b.len();
    b[n - 40] ^= 1;
    fs::write(&p, &b).unwrap();
    assert!(matches!(
        nimbus::io::inspect::describe(&p),
        Err(Error::InvalidInput(_))
    ));
}

#[test]
fn inconsistent_checkpoints_are_refused_on_write() {
    let dir = tempfile::tempdir().unwrap();
    let mut ck = checkpoint(1, 4, 1);
    ck.state.density.pop();
    let e = ckpt::write_checkpoint(dir.path(), &ck).unwrap_err();
    assert!(matches!(e, Error::Runtime(_)), "{e:?}");
    let mut ck = checkpoint(1, 4, 1);
    ck.extra.insert("pos".into(), vec![1]);
    assert!(matches!(
        ckpt::write_checkpoint(dir.path(), &ck),
        Err(Error::Runtime(_))
    ));
    let mut ck = checkpoint(1, 4, 1);
    ck.header.capacity = 3;
    assert!(matches!(
        ckpt::write_checkpoint(dir.path(), &ck),
        Err(Error::Runtime(_))
    ));
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
}

/// Checks the state after a failed write: an Io error (exit 3) naming the checkpoint and the
/// reason, the previous checkpoint and finished frame byte-identical, no temporary file.
fn assert_failed_cleanly(
    r: nimbus::Result<PathBuf>,
    d: &Path,
    prev: &(PathBuf, Vec<u8>),
    frame_file: &(PathBuf, Vec<u8>),
    why: &str,
) {
    let e = r.expect_err("write into a failing disk succeeded");
    assert!(matches!(e, Error::Io { .. }), "{e:?}");
    assert_eq!(e.exit_code(), 3);
    let msg = e.to_string();
    assert!(msg.contains("ckpt_000002.nck"), "{msg}");
    assert!(msg.contains(why), "{msg}");
    assert_eq!(fs::read(&prev.0).unwrap(), prev.1);
    assert_eq!(fs::read(&frame_file.0).unwrap(), frame_file.1);
    assert!(tmp_files(d).is_empty(), "{:?}", tmp_files(d));
    assert!(!d.join(ckpt::file_name(2)).exists());
    ckpt::read_checkpoint(&prev.0).unwrap();
}

#[test]
fn injected_write_errors_leave_everything_intact() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let prev = written(d, &checkpoint(1, 50, 1));
    let frame_file = (d.join("frame_0001.vdb"), b"finished frame".to_vec());
    fs::write(&frame_file.0, &frame_file.1).unwrap();
    let next = checkpoint(2, 400, 2);
    let full_len = written(tempfile::tempdir().unwrap().path(), &next).1.len() as u64;
    for fail_after in [0, 1, 17, 200, full_len / 2, full_len - 33, full_len - 1] {
        let r = ckpt::write_checkpoint_failing_after(d, &next, fail_after);
        assert_failed_cleanly(r, d, &prev, &frame_file, "No space left on device");
    }
    // Enough room: the same hook writes a valid file.
    let p = ckpt::write_checkpoint_failing_after(d, &next, full_len).unwrap();
    assert_bit_identical(&ckpt::read_checkpoint(&p).unwrap(), &next);
}

#[test]
fn checkpoint_dir_that_cannot_be_created_is_an_io_error() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("not_a_dir");
    fs::write(&file, b"x").unwrap();
    let e = ckpt::write_checkpoint(&file.join("checkpoints"), &checkpoint(1, 2, 1)).unwrap_err();
    assert!(matches!(e, Error::Io { .. }) && e.exit_code() == 3, "{e:?}");
    assert!(e.to_string().contains("not_a_dir"), "{e}");
    assert_eq!(fs::read(&file).unwrap(), b"x");
}

/// Unmounts the test tmpfs even when an assertion fails.
struct Mount(PathBuf);
impl Drop for Mount {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount").arg(&self.0).status();
    }
}

#[test]
fn full_tmpfs_gives_a_clear_error_and_keeps_previous_files() {
    let outer = tempfile::tempdir().unwrap();
    let d = outer.path().join("mnt");
    fs::create_dir(&d).unwrap();
    let mounted = std::process::Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=64k", "tmpfs"])
        .arg(&d)
        .stderr(std::process::Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if !mounted {
        eprintln!("note: cannot mount a tmpfs here (not root or not allowed); skipping the real full-disk variant");
        return;
    }
    let _guard = Mount(d.clone());
    let prev = written(&d, &checkpoint(1, 100, 1)); // ~6 KB
    let frame_file = (d.join("frame_0001.vdb"), vec![7u8; 8000]);
    fs::write(&frame_file.0, &frame_file.1).unwrap();
    // ~120 KB: cannot fit in 64 KiB.
    let r = ckpt::write_checkpoint(&d, &checkpoint(2, 2000, 2));
    assert_failed_cleanly(r, &d, &prev, &frame_file, "No space left on device");
    // The space is back: a checkpoint that fits is written after the failure.
    let p = ckpt::write_checkpoint(&d, &checkpoint(2, 200, 2)).unwrap();
    ckpt::read_checkpoint(&p).unwrap();
}

/// Measurement, not a test of speed: `cargo test --release --test checkpoint -- --ignored
/// --nocapture bench` prints the figures recorded in docs/PERFORMANCE.md.
#[test]
#[ignore]
fn bench_checkpoint_sizes_and_times() {
    for n in [100_000usize, 1_000_000] {
        let v = nimbus::bench::checkpoint::bench_checkpoint(n).unwrap();
        println!("{v}");
        let per = v["bytes_per_particle"].as_f64().unwrap();
        assert!((60.0..60.01).contains(&per), "{per}");
    }
}
