//! `voxray info`: validates an `.svo` file and prints its sizes.

use super::*;

pub(crate) fn info_cmd(file: &Path) -> Result<(), Error> {
    let svo = voxray::svo::io::load(file)?;
    let s = svo.stats();
    match voxray::svo::io::file_version(file) {
        Some(v) if v < voxray::svo::io::VERSION => println!(
            "{}: valid, format version {v}, converted on load to version {} (`voxray voxelize` writes the current version)",
            file.display(),
            voxray::svo::io::VERSION
        ),
        _ => println!("{}: valid", file.display()),
    }
    println!("  bounds: min {:?}, size {}", svo.bounds.min, svo.bounds.size);
    println!("  depth {}, voxel size {}", s.depth, svo.bounds.voxel_size(s.depth));
    println!("  voxels {}, nodes {}, attributes {}", s.voxels, s.nodes, s.attributes);
    println!(
        "  geometry (what traversal reads) {} B ({:.2} B/voxel), attributes (read for hits) {} B ({:.2} B/voxel)",
        s.geometry_bytes,
        s.geometry_bytes_per_voxel(),
        s.attribute_bytes,
        s.attribute_bytes_per_voxel()
    );
    Ok(())
}
