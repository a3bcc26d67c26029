//! `voxray model`: writes the built-in models as OBJ/MTL.

use super::*;

pub(crate) fn model_cmd(model: &str, out_dir: Option<&Path>) -> Result<(), Error> {
    let out_dir = out_dir.map_or_else(|| Path::new("models").join(model), Path::to_path_buf);
    std::fs::create_dir_all(&out_dir).map_err(|source| Error::Io { path: out_dir.display().to_string(), source })?;
    let files = match model {
        "box" => voxray::model::room::files(),
        "thick-box" => voxray::model::room::thick_files(),
        "panel-room" => voxray::model::panel_room::files(),
        _ => voxray::model::car::files(),
    };
    for (name, text) in files {
        let p = out_dir.join(&name);
        output::write_file(&p, text.as_bytes())
            .map_err(|source| Error::Io { path: p.display().to_string(), source })?;
        println!("wrote {}", p.display());
    }
    Ok(())
}
