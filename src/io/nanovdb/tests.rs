use super::*;
use crate::ground::{GridTransform, Leaf, SparseGrid, LEAF_VOXELS};

/// A small cloud-like grid spanning two upper nodes (negative and positive coordinates) with
/// partly filled leaves.
pub(crate) fn sample_grid() -> SparseGrid<f32> {
    let mut leaves = Vec::new();
    for o in [
        [-4096, 0, 8],
        [0, 0, 0],
        [0, 8, 0],
        [8, 120, 16],
        [128, 0, 0],
    ] {
        let mut values = Box::new([0f32; LEAF_VOXELS]);
        let mut mask = [0u64; 8];
        for n in 0..LEAF_VOXELS {
            let h = (n as u32 ^ (o[0] as u32).wrapping_mul(31) ^ (o[1] as u32).wrapping_mul(7))
                .wrapping_mul(2_654_435_761);
            if !h.is_multiple_of(3) {
                values[n] = (h >> 8) as f32 / (1u32 << 24) as f32 * 1.7;
                mask[n / 64] |= 1 << (n % 64);
            }
        }
        leaves.push(Leaf {
            origin: o,
            values,
            mask,
        });
    }
    SparseGrid {
        name: "density".into(),
        background: 0.0,
        transform: GridTransform {
            voxel_size: 20.0,
            origin: [10.0, -30.0, 10.0],
        },
        leaves,
    }
}

fn float_leaves(g: &NanoFileGrid) -> &Vec<Leaf<f32>> {
    match &g.leaves {
        Leaves::Float(v) => v,
        Leaves::Vec3(_) => panic!("not a float grid"),
    }
}

#[test]
fn float_grid_round_trips_bit_for_bit() {
    let g = sample_grid();
    let grid = NanoGrid {
        name: "density".into(),
        class: GridClass::FogVolume,
        values: NanoValues::Float(&g, Quantise::Float),
    };
    let bytes = encode(std::slice::from_ref(&grid)).unwrap().to_bytes();
    let back = read_bytes(&bytes).unwrap();
    assert_eq!(back.len(), 1);
    let b = &back[0];
    assert!(b.checksum_ok);
    assert_eq!(b.name, "density");
    assert_eq!(b.grid_type, GridType::Float);
    assert_eq!(b.active_voxels, g.active_voxel_count());
    assert_eq!(b.voxel_size, 20.0);
    assert_eq!(b.origin, [10.0, -30.0, 10.0]);
    let mut want: Vec<_> = g
        .leaves
        .iter()
        .map(|l| (l.origin, l.mask, l.values.to_vec()))
        .collect();
    want.sort_by_key(|w| crate::io::vdb::write::tree_key(w.0));
    let got: Vec<_> = float_leaves(b)
        .iter()
        .map(|l| (l.origin, l.mask, l.values.to_vec()))
        .collect();
    assert_eq!(got, want);
    // Deterministic, and a changed value changes the checksum.
    assert_eq!(
        encode(std::slice::from_ref(&grid)).unwrap().to_bytes(),
        bytes
    );
    let mut bad = bytes.clone();
    let last = bad.len() - 4;
    bad[last] ^= 1;
    assert!(!read_bytes(&bad).unwrap()[0].checksum_ok);
}

#[test]
fn quantised_grids_stay_within_the_quantum() {
    let g = sample_grid();
    for (q, bits) in [(Quantise::Fp4, 4), (Quantise::Fp8, 8), (Quantise::Fp16, 16)] {
        let grid = NanoGrid {
            name: "d".into(),
            class: GridClass::FogVolume,
            values: NanoValues::Float(&g, q),
        };
        let b = &read_bytes(&encode(&[grid]).unwrap().to_bytes()).unwrap()[0];
        assert!(b.checksum_ok, "{q:?}");
        for leaf in float_leaves(b) {
            let src = g.leaves.iter().find(|l| l.origin == leaf.origin).unwrap();
            let vals: Vec<f32> = (0..LEAF_VOXELS)
                .map(|n| if src.is_active(n) { src.values[n] } else { 0.0 })
                .collect();
            let (lo, hi) = vals
                .iter()
                .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            let quantum = (hi - lo) / ((1u32 << bits) - 1) as f32;
            for (n, (got, want)) in leaf.values.iter().zip(&vals).enumerate() {
                let err = (got - want).abs();
                assert!(
                    err <= quantum * 0.5 + 1e-6,
                    "{q:?} leaf {:?} voxel {n}: {err} > {}",
                    leaf.origin,
                    quantum / 2.0
                );
            }
        }
    }
    for tol in [0.001f32, 0.05, 0.5] {
        let grid = NanoGrid {
            name: "d".into(),
            class: GridClass::FogVolume,
            values: NanoValues::Float(&g, Quantise::FpN { tolerance: tol }),
        };
        let b = &read_bytes(&encode(&[grid]).unwrap().to_bytes()).unwrap()[0];
        assert!(b.checksum_ok);
        for leaf in float_leaves(b) {
            let src = g.leaves.iter().find(|l| l.origin == leaf.origin).unwrap();
            for n in (0..LEAF_VOXELS).filter(|&n| src.is_active(n)) {
                let err = (leaf.values[n] - src.values[n]).abs();
                // 16 bits is the fallback when no narrower width meets the tolerance.
                let q16 = 1.7 / 65535.0;
                assert!(err <= tol.max(q16), "FpN {tol}: {err}");
            }
        }
    }
}

#[test]
fn vector_and_empty_grids() {
    let s = sample_grid();
    let v = SparseGrid {
        name: "vel".into(),
        background: [0.0f32; 3],
        transform: s.transform,
        leaves: s
            .leaves
            .iter()
            .map(|l| Leaf {
                origin: l.origin,
                values: Box::new(l.values.map(|x| [x, -2.0 * x, 0.5])),
                mask: l.mask,
            })
            .collect(),
    };
    let empty = SparseGrid {
        leaves: vec![],
        ..s.clone()
    };
    let grids = [
        NanoGrid {
            name: "vel".into(),
            class: GridClass::Unknown,
            values: NanoValues::Vec3(&v),
        },
        NanoGrid {
            name: "density".into(),
            class: GridClass::FogVolume,
            values: NanoValues::Float(&empty, Quantise::Fp8),
        },
    ];
    let back = read_bytes(&encode(&grids).unwrap().to_bytes()).unwrap();
    assert_eq!(back.len(), 2);
    assert!(back.iter().all(|g| g.checksum_ok));
    assert_eq!(back[0].grid_type, GridType::Vec3f);
    assert_eq!(back[1].bbox, None);
    assert_eq!(back[1].bytes, 800);
    let Leaves::Vec3(leaves) = &back[0].leaves else {
        panic!()
    };
    for leaf in leaves {
        let src = v.leaves.iter().find(|l| l.origin == leaf.origin).unwrap();
        for n in 0..LEAF_VOXELS {
            let want = if src.is_active(n) {
                src.values[n]
            } else {
                [0.0; 3]
            };
            assert_eq!(leaf.values[n], want);
        }
    }
    // Duplicate names are refused.
    let dup = [grids[1].clone(), grids[1].clone()];
    assert!(encode(&dup).is_err());
}
