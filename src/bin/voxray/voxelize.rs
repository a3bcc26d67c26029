//! `voxray voxelize`: writes each part's `.svo` file.

use super::*;

pub(crate) fn voxelize_cmd(a: VoxelizeArgs) -> Result<(), Error> {
    let mesh = load_mesh(&a.source)?;
    let parts = build_parts(&mesh, &a.source)?;
    std::fs::create_dir_all(&a.out_dir)
        .map_err(|source| Error::Io { path: a.out_dir.display().to_string(), source })?;
    for (part, svo) in mesh.parts.iter().zip(&parts) {
        let safe: String =
            part.name.chars().map(|c| if c.is_alphanumeric() || c == '_' || c == '-' { c } else { '_' }).collect();
        let path = a.out_dir.join(format!("{safe}.svo"));
        voxray::svo::io::save(svo, &path)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
