//! `voxray voxelize`: writes each part's `.svo` file.

use super::*;

pub(crate) fn voxelize_cmd(a: VoxelizeArgs) -> Result<(), Error> {
    let mesh = load_mesh(&a.source)?;
    let parts = build_parts(&mesh, &a.source)?;
    std::fs::create_dir_all(&a.out_dir)
        .map_err(|source| Error::Io { path: a.out_dir.display().to_string(), source })?;
    let mut taken = std::collections::HashSet::new();
    for (part, svo) in mesh.parts.iter().zip(&parts) {
        let safe: String =
            part.name.chars().map(|c| if c.is_alphanumeric() || c == '_' || c == '-' { c } else { '_' }).collect();
        // Two parts of one name (or names that differ only in replaced characters) each get
        // a file: the later ones are numbered, with a warning, instead of overwriting.
        let mut name = safe.clone();
        let mut k = 2;
        while !taken.insert(name.to_lowercase()) {
            name = format!("{safe}_{k}");
            k += 1;
        }
        if name != safe {
            eprintln!("warning: another part is also named '{}': writing this one as {name}.svo", part.name);
        }
        let path = a.out_dir.join(format!("{name}.svo"));
        voxray::svo::io::save(svo, &path)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
