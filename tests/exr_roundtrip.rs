//! The density atlas EXR reads back with the exr crate (pixels and attributes) and with
//! `exrheader` (skipped with a note when absent); the same grid gives the same bytes.
use exr::prelude::*;
use nimbus::ground::{GridTransform, Leaf, SparseGrid, LEAF_VOXELS};
use nimbus::io::exr::{atlas_layout, encode_density_atlas, write_density_atlas};
use std::collections::BTreeMap;
use std::process::Command;

fn grid(voxels: &BTreeMap<[i32; 3], f32>) -> SparseGrid<f32> {
    let mut leaves: BTreeMap<[i32; 3], Leaf<f32>> = BTreeMap::new();
    for (&p, &v) in voxels {
        let o = p.map(|c| c & !7);
        let leaf = leaves.entry(o).or_insert_with(|| Leaf {
            origin: o,
            values: Box::new([0.0; LEAF_VOXELS]),
            mask: [0; 8],
        });
        let n = Leaf::<f32>::offset(p[0], p[1], p[2]);
        leaf.values[n] = v;
        leaf.mask[n / 64] |= 1 << (n % 64);
    }
    SparseGrid {
        name: "density".into(),
        background: 0.0,
        transform: GridTransform {
            voxel_size: 20.0,
            origin: [-500.0, 10.0, 250.0],
        },
        leaves: leaves.into_values().collect(),
    }
}

fn blob() -> BTreeMap<[i32; 3], f32> {
    let mut v = BTreeMap::new();
    for x in -6..9 {
        for y in 2..13 {
            for z in -3..4 {
                if (x + y + z) % 4 != 0 {
                    v.insert([x, y, z], 0.01 * (x * 100 + y * 10 + z) as f32 + 3.0);
                }
            }
        }
    }
    v
}

fn attr<'a>(layer: &'a exr::meta::header::LayerAttributes, k: &str) -> &'a AttributeValue {
    layer
        .other
        .get(&Text::from(k))
        .unwrap_or_else(|| panic!("attribute {k} missing"))
}

#[test]
fn atlas_reads_back_with_pixels_and_attributes() {
    let v = blob();
    let g = grid(&v);
    let dir = tempfile::tempdir().unwrap();
    for half in [false, true] {
        let p = dir.path().join(format!("a_{half}.exr"));
        let n = write_density_atlas(&p, &g, half).unwrap();
        assert_eq!(n, std::fs::metadata(&p).unwrap().len());
        let img = read_all_flat_layers_from_file(&p).unwrap();
        let layer = &img.layer_data[0];
        let size = [15usize, 11, 7];
        let (cols, rows) = atlas_layout(size);
        assert_eq!((cols, rows), (3, 3));
        assert_eq!(layer.size, Vec2(cols * 15, rows * 11));
        assert_eq!(
            layer.encoding.compression,
            exr::compression::Compression::ZIP16
        );
        assert_eq!(layer.encoding.line_order, LineOrder::Increasing);
        let a = &layer.attributes;
        assert_eq!(attr(a, "slices"), &AttributeValue::I32(7));
        assert_eq!(attr(a, "atlasColumns"), &AttributeValue::I32(3));
        assert_eq!(attr(a, "gridSize"), &AttributeValue::IntVec3((15, 11, 7)));
        assert_eq!(attr(a, "bboxMin"), &AttributeValue::IntVec3((-6, 2, -3)));
        assert_eq!(attr(a, "voxelSize"), &AttributeValue::F64(20.0));
        assert_eq!(
            attr(a, "origin"),
            &AttributeValue::FloatVec3((-500.0, 10.0, 250.0))
        );
        let ch = &layer.channel_data.list[0];
        assert_eq!(ch.name, Text::from("density"));
        let w = cols * 15;
        let px = |x: i32, y: i32, z: i32| {
            let k = (z + 3) as usize;
            let col = (k % cols) * 15 + (x + 6) as usize;
            let row = (k / cols) * 11 + (10 - (y - 2) as usize);
            ch.sample_data.value_by_flat_index(row * w + col).to_f32()
        };
        let mut sum_img = 0.0f64;
        for i in 0..layer.size.area() {
            sum_img += ch.sample_data.value_by_flat_index(i).to_f32() as f64;
        }
        let mut sum = 0.0f64;
        for (&p, &val) in &v {
            let want = if half {
                f16::from_f32(val).to_f32()
            } else {
                val
            };
            assert_eq!(px(p[0], p[1], p[2]), want, "{p:?}");
            sum += want as f64;
        }
        assert!((sum - sum_img).abs() < 1e-3, "inactive pixels are zero");
        // Deterministic bytes (custom attributes are sorted, not in hash order).
        assert_eq!(
            encode_density_atlas(&g, half).unwrap(),
            std::fs::read(&p).unwrap()
        );
    }
}

#[test]
fn empty_grid_gives_a_tiny_valid_image() {
    let g = grid(&BTreeMap::new());
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("empty.exr");
    write_density_atlas(&p, &g, false).unwrap();
    let img = read_all_flat_layers_from_file(&p).unwrap();
    let layer = &img.layer_data[0];
    assert_eq!(layer.size, Vec2(1, 1));
    assert_eq!(attr(&layer.attributes, "slices"), &AttributeValue::I32(0));
    assert_eq!(
        attr(&layer.attributes, "gridSize"),
        &AttributeValue::IntVec3((0, 0, 0))
    );
}

#[test]
fn exrheader_reads_the_atlas() {
    if Command::new("exrheader").output().is_err() {
        eprintln!("note: exrheader absent; check skipped");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.exr");
    write_density_atlas(&p, &grid(&blob()), true).unwrap();
    let out = Command::new("exrheader").arg(&p).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    for want in [
        "density, 16-bit floating-point",
        "zip",
        "increasing y",
        "slices",
        "gridSize",
        "voxelSize",
        "origin",
        "atlasColumns",
    ] {
        assert!(
            text.contains(want),
            "exrheader output lacks {want:?}:\n{text}"
        );
    }
}

#[test]
fn inspect_describes_vdb_and_exr() {
    use nimbus::io::vdb::{self, VdbFile, VdbGrid, VdbOptions};
    let dir = tempfile::tempdir().unwrap();
    let g = grid(&blob());
    let e = dir.path().join("a.exr");
    write_density_atlas(&e, &g, false).unwrap();
    let d = nimbus::io::inspect::describe(&e).unwrap();
    assert!(d.contains("density") && d.contains("slices"), "{d}");
    let p = dir.path().join("a.vdb");
    let file = VdbFile {
        grids: vec![VdbGrid::float("density", g.clone()).with_alias("smoke")],
        metadata: VdbFile::standard_metadata(3),
    };
    vdb::write_file(&p, &file, &VdbOptions::default()).unwrap();
    let d = nimbus::io::inspect::describe(&p).unwrap();
    let s = nimbus::io::inspect::stats(&g, |v| *v as f64);
    for want in [
        "grid 'density': Tree_float_5_4_3 class 'fog volume'".to_string(),
        "instance of 'density'".to_string(),
        format!("active voxels: {}", s.active),
        format!("sum {:.9e}", s.sum),
        "voxel size: 20".to_string(),
        "bbox: [-6, 2, -3] .. [8, 12, 3]".to_string(),
    ] {
        assert!(d.contains(&want), "{want:?} missing in:\n{d}");
    }
    let junk = dir.path().join("junk.bin");
    std::fs::write(&junk, b"hello").unwrap();
    assert!(matches!(
        nimbus::io::inspect::describe(&junk),
        Err(nimbus::Error::InvalidInput(_))
    ));
}
