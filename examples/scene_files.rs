//! Writes two large scene files for timing the loaders (docs/benchmarks.md, "Loading scene
//! files"): `spheres.glb`, four UV-sphere meshes of 250 000 triangles each (1 M triangles)
//! placed by eight nodes under a spinning parent, and `terrain.vox`, one 256³ MagicaVoxel model
//! of a filled height field (about 6 M voxels) placed twice, with a two-frame flip-book.
//!
//! `cargo run --release --example scene_files -- OUT_DIR`

use std::io::Write;

fn sphere(rings: u32, segments: u32) -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut pos = Vec::new();
    for r in 0..=rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            pos.push([theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin()]);
        }
    }
    let mut idx = Vec::new();
    for r in 0..rings {
        for s in 0..segments {
            let (a, b) = (r * segments + s, r * segments + (s + 1) % segments);
            let (c, d) = (a + segments, b + segments);
            idx.extend_from_slice(&[a, c, b, b, c, d]);
        }
    }
    (pos, idx)
}

fn glb(path: &std::path::Path) -> std::io::Result<()> {
    let mut bin: Vec<u8> = Vec::new();
    let (mut views, mut accessors, mut meshes) = (Vec::new(), Vec::new(), Vec::new());
    let mut view = |bin: &mut Vec<u8>, bytes: &[u8]| {
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        views.push(format!(r#"{{"buffer":0,"byteOffset":{},"byteLength":{}}}"#, bin.len(), bytes.len()));
        bin.extend_from_slice(bytes);
        views.len() - 1
    };
    for m in 0..4 {
        // 250 rings × 500 segments × 2 = 250 000 triangles, squashed differently per mesh.
        let (pos, idx) = sphere(250, 500);
        let squash = [1.0, 0.6 + 0.1 * m as f32, 1.0];
        let pos: Vec<[f32; 3]> = pos.iter().map(|p| [p[0] * squash[0], p[1] * squash[1], p[2] * squash[2]]).collect();
        let pb: Vec<u8> = pos.iter().flat_map(|p| p.iter().flat_map(|c| c.to_le_bytes())).collect();
        let ib: Vec<u8> = idx.iter().flat_map(|i| i.to_le_bytes()).collect();
        let (pv, iv) = (view(&mut bin, &pb), view(&mut bin, &ib));
        accessors.push(format!(
            r#"{{"bufferView":{pv},"componentType":5126,"count":{},"type":"VEC3","min":[-1,-1,-1],"max":[1,1,1]}}"#,
            pos.len()
        ));
        accessors.push(format!(r#"{{"bufferView":{iv},"componentType":5125,"count":{},"type":"SCALAR"}}"#, idx.len()));
        meshes.push(format!(
            r#"{{"name":"sphere {m}","primitives":[{{"attributes":{{"POSITION":{}}},"indices":{},"material":{m}}}]}}"#,
            accessors.len() - 2,
            accessors.len() - 1
        ));
    }
    // The spin: four keys of a turn about y over 4 s.
    let times: Vec<u8> = [0.0f32, 1.0, 2.0, 3.0, 4.0].iter().flat_map(|t| t.to_le_bytes()).collect();
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let quats: Vec<u8> =
        [[0.0, 0.0, 0.0, 1.0], [0.0, h, 0.0, h], [0.0, 1.0, 0.0, 0.0], [0.0, h, 0.0, -h], [0.0, 0.0, 0.0, -1.0]]
            .iter()
            .flat_map(|q: &[f32; 4]| q.iter().flat_map(|c| c.to_le_bytes()).collect::<Vec<_>>())
            .collect();
    let (tv, qv) = (view(&mut bin, &times), view(&mut bin, &quats));
    accessors
        .push(format!(r#"{{"bufferView":{tv},"componentType":5126,"count":5,"type":"SCALAR","min":[0],"max":[4]}}"#));
    accessors.push(format!(r#"{{"bufferView":{qv},"componentType":5126,"count":5,"type":"VEC4"}}"#));
    let (ta, qa) = (accessors.len() - 2, accessors.len() - 1);
    let mut nodes = vec![r#"{"name":"turntable","children":[1,2,3,4,5,6,7,8]}"#.to_string()];
    for k in 0..8 {
        let angle = std::f32::consts::TAU * k as f32 / 8.0;
        nodes.push(format!(
            r#"{{"name":"ball {k}","mesh":{},"translation":[{},0,{}],"scale":[0.8,0.8,0.8]}}"#,
            k % 4,
            4.0 * angle.cos(),
            4.0 * angle.sin()
        ));
    }
    let materials: Vec<String> = [[0.8, 0.2, 0.1], [0.2, 0.6, 0.2], [0.2, 0.3, 0.8], [0.8, 0.7, 0.2]]
        .iter()
        .map(|c| {
            format!(
                r#"{{"pbrMetallicRoughness":{{"baseColorFactor":[{},{},{},1],"metallicFactor":0}}}}"#,
                c[0], c[1], c[2]
            )
        })
        .collect();
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let json = format!(
        r#"{{"asset":{{"version":"2.0","generator":"voxray examples/scene_files.rs"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{}],"meshes":[{}],"materials":[{}],"accessors":[{}],"bufferViews":[{}],"buffers":[{{"byteLength":{}}}],"animations":[{{"name":"spin","samplers":[{{"input":{ta},"output":{qa},"interpolation":"LINEAR"}}],"channels":[{{"sampler":0,"target":{{"node":0,"path":"rotation"}}}}]}}]}}"#,
        nodes.join(","),
        meshes.join(","),
        materials.join(","),
        accessors.join(","),
        views.join(","),
        bin.len()
    );
    let mut j = json.into_bytes();
    while j.len() % 4 != 0 {
        j.push(b' ');
    }
    let mut f = std::fs::File::create(path)?;
    f.write_all(b"glTF")?;
    f.write_all(&2u32.to_le_bytes())?;
    f.write_all(&((12 + 8 + j.len() + 8 + bin.len()) as u32).to_le_bytes())?;
    f.write_all(&(j.len() as u32).to_le_bytes())?;
    f.write_all(b"JSON")?;
    f.write_all(&j)?;
    f.write_all(&(bin.len() as u32).to_le_bytes())?;
    f.write_all(b"BIN\0")?;
    f.write_all(&bin)
}

fn vox(path: &std::path::Path) -> std::io::Result<()> {
    use dot_vox::{Dict, DotVoxData, Frame, Model, SceneNode, ShapeModel, Size, Voxel};
    let terrain = |phase: f32| {
        let mut voxels = Vec::new();
        for x in 0..256u32 {
            for y in 0..256u32 {
                let (fx, fy) = (x as f32 / 256.0, y as f32 / 256.0);
                let h =
                    96.0 + 40.0 * (fx * 9.0 + phase).sin() * (fy * 7.0).cos() + 20.0 * (fx * 23.0 + fy * 17.0).sin();
                let top = (h.clamp(1.0, 255.0)) as u32;
                for z in 0..top {
                    let colour = if z + 4 >= top {
                        120
                    } else if z < 40 {
                        200
                    } else {
                        150
                    };
                    voxels.push(Voxel { x: x as u8, y: y as u8, z: z as u8, i: colour });
                }
            }
        }
        Model { size: Size { x: 256, y: 256, z: 256 }, voxels }
    };
    let dict = |pairs: &[(&str, &str)]| -> Dict { pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect() };
    let data = DotVoxData {
        version: 150,
        index_map: Vec::new(),
        models: vec![terrain(0.0), terrain(1.5)],
        palette: dot_vox::DEFAULT_PALETTE.to_vec(),
        materials: Vec::new(),
        scenes: vec![
            SceneNode::Transform { attributes: dict(&[]), frames: vec![Frame::new(dict(&[]))], child: 1, layer_id: 0 },
            SceneNode::Group { attributes: dict(&[]), children: vec![2, 4] },
            SceneNode::Transform {
                attributes: dict(&[("_name", "west")]),
                frames: vec![Frame::new(dict(&[("_t", "-128 0 0")]))],
                child: 3,
                layer_id: 0,
            },
            SceneNode::Shape {
                attributes: dict(&[]),
                models: vec![
                    ShapeModel { model_id: 0, attributes: dict(&[("_f", "0")]) },
                    ShapeModel { model_id: 1, attributes: dict(&[("_f", "5")]) },
                ],
            },
            SceneNode::Transform {
                attributes: dict(&[("_name", "east")]),
                frames: vec![Frame::new(dict(&[("_t", "128 0 0"), ("_r", "20")]))],
                child: 5,
                layer_id: 0,
            },
            SceneNode::Shape { attributes: dict(&[]), models: vec![ShapeModel { model_id: 0, attributes: dict(&[]) }] },
        ],
        layers: Vec::new(),
    };
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    data.write_vox(&mut f)
}

fn main() -> std::io::Result<()> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| ".".into()));
    std::fs::create_dir_all(&dir)?;
    glb(&dir.join("spheres.glb"))?;
    println!("wrote {}", dir.join("spheres.glb").display());
    vox(&dir.join("terrain.vox"))?;
    println!("wrote {}", dir.join("terrain.vox").display());
    Ok(())
}
