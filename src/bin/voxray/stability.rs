//! `voxray stability`: the numerical-stability suite against the DDA oracle.

use super::*;

pub(crate) fn stability_cmd(rays: usize, out: Option<PathBuf>) -> Result<(), Error> {
    use voxray::stability::{run_case, run_transform_case, standard_cases, table, transform_cases};
    let t = Instant::now();
    let cases = standard_cases(rays);
    let tcases = transform_cases(24_000);
    let pb = bar((cases.len() + tcases.len()) as u64, "stability cases");
    let mut reports: Vec<_> = cases
        .iter()
        .map(|c| {
            let r = run_case(c);
            pb.inc(1);
            r
        })
        .collect();
    reports.extend(tcases.iter().map(|c| {
        let r = run_transform_case(c);
        pb.inc(1);
        r
    }));
    pb.finish_and_clear();
    let tbl = table(&reports);
    println!("{tbl}");
    let bad: u64 = reports.iter().map(|r| r.mismatches + r.nan + r.aborted).sum();
    println!(
        "{} rays in {:.1}s; {bad} failures",
        reports.iter().map(|r| r.rays).sum::<u64>(),
        t.elapsed().as_secs_f64()
    );
    if let Some(p) = out {
        let md = format!(
            "# Stability suite\n\nProduced by `voxray stability --rays {rays} --out {}` (release build; `cargo test` runs \
             the same cases through `tests/stability.rs` and fails on any NaN, mismatch or aborted loop).\n\n\
             Each row traces a family of stiff or adversarial rays through an SVO and compares every ray with the \
             brute-force Amanatides–Woo DDA oracle (`src/oracle.rs`, f64, no octree). Columns:\n\n\
             - **oracle hits**: rays the oracle says hit a voxel (the rest must miss).\n\
             - **NaN**: results with a non-finite t or normal.\n\
             - **misses vs oracle**: wrong voxel, wrong t, or hit/miss disagreement.\n\
             - **accepted ties**: the ray passes exactly through an edge or corner (or starts on a face), so several \
             voxels are touched at the same t; the answer is accepted only if the voxel named is occupied, touched \
             within 10⁻⁶ (relative) at that t, and no voxel is entered for longer than that before it.\n\
             - **max rel. |Δt|**: largest |t − exact f64 entry t of the voxel| / max(|t|, one cube width in t); the \
             bound is 10⁻⁵.\n\
             - **max loop count / loop bound**: iterations of the traversal loop against the proven bound \
             5·(3·(2^depth − 1) + depth) + 1 (`traverse::step_bound`; not recorded for the instance rows).\n\n\
             The `instance:` rows place the SVO with a transform (or a parent and a child transform) and trace \
             world rays the way the renderer does (camera-relative f64 maps, the instance search of \
             `render::visibility`); the oracle walks the same ray mapped into the unit cube in f64.\n\n{tbl}",
            p.display()
        );
        output::write_file(&p, md.as_bytes()).map_err(|source| Error::Io { path: p.display().to_string(), source })?;
        println!("wrote {}", p.display());
    }
    if bad > 0 {
        return Err(Error::Io {
            path: "stability".into(),
            source: std::io::Error::other(format!("{bad} rays disagree with the oracle")),
        });
    }
    Ok(())
}
