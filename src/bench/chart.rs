//! PNG charts of benchmark records (plotters, with an embedded DejaVu font so they draw the
//! same on a machine without fonts): bars for the paper comparison and the peers, log-log
//! lines for instance scaling, lines for resolution, and error against run time for LOD.

use super::Record;
use plotters::prelude::*;
use std::path::Path;

/// Why a chart could not be drawn.
#[derive(Debug, thiserror::Error)]
#[error("chart {path}: {msg}")]
pub struct ChartError {
    /// The file.
    pub path: String,
    /// What went wrong.
    pub msg: String,
}

const SIZE: (u32, u32) = (900, 520);
const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // A failure leaves plotters without a font; drawing then reports the error.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular());
    });
}

type Res<T> = Result<T, Box<dyn std::error::Error>>;

/// The series labels, boxed in the upper left (every chart's legend).
fn legend<'a, DB, CT>(chart: &mut ChartContext<'a, DB, CT>) -> Res<()>
where
    DB: DrawingBackend + 'a,
    DB::ErrorType: 'static,
    CT: CoordTranslate,
{
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()?;
    Ok(())
}

/// Draws one chart from the records of its group.
type Drawer = fn(&[&Record], &Path) -> Res<()>;

/// A named line of labelled (x, y) points.
type Series = (String, Vec<(f64, f64, String)>);

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// Draws into an RGB buffer and writes it as PNG (plotters' own encoder is left out; the
/// image crate is already here).
fn png(path: &Path, draw: impl FnOnce(&Area<'_>) -> Res<()>) -> Res<()> {
    png_sized(path, SIZE, draw)
}

/// [`png`] at another size.
fn png_sized(path: &Path, size: (u32, u32), draw: impl FnOnce(&Area<'_>) -> Res<()>) -> Res<()> {
    let mut buf = vec![255u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
    }
    let img = image::RgbImage::from_raw(size.0, size.1, buf).ok_or("chart buffer size")?;
    img.save(path)?;
    Ok(())
}

/// Draws every chart the records allow into `dir` and returns (group, file name) pairs.
pub fn draw_all(records: &[Record], dir: &Path) -> Result<Vec<(String, String)>, ChartError> {
    register_font();
    std::fs::create_dir_all(dir).map_err(|e| ChartError { path: dir.display().to_string(), msg: e.to_string() })?;
    let mut out = Vec::new();
    let jobs: [(&str, &str, Drawer); 11] = [
        ("paper", "bench-paper.png", paper),
        ("instances", "bench-instances.png", instances),
        ("splat", "bench-splat.png", splat),
        ("resolution", "bench-resolution.png", resolution),
        ("depth", "bench-depth.png", depth),
        ("peers", "bench-peers.png", peers),
        ("gi-scaling", "bench-gi-scaling.png", gi_scaling),
        ("gi-accuracy", "accuracy-gi.png", gi_accuracy),
        ("gi-accuracy", "accuracy-gi-panel.png", gi_accuracy_panel),
        ("gi-accuracy", "accuracy-gi-car.png", gi_accuracy_car),
        ("gi-accuracy", "accuracy-gi-thick.png", gi_accuracy_thick),
    ];
    for (group, file, draw) in jobs {
        let rs: Vec<&Record> = records.iter().filter(|r| r.group == group).collect();
        if rs.is_empty() {
            continue;
        }
        let path = dir.join(file);
        draw(&rs, &path).map_err(|e| ChartError { path: path.display().to_string(), msg: e.to_string() })?;
        out.push((group.to_string(), file.to_string()));
    }
    Ok(out)
}

fn kinds(rs: &[&Record]) -> Vec<String> {
    let mut k: Vec<String> = Vec::new();
    for r in rs {
        if !k.contains(&r.backend_kind) {
            k.push(r.backend_kind.clone());
        }
    }
    k
}

/// Grouped bars: one group per distinct `label`, one bar per series.
fn bars(path: &Path, title: &str, y_desc: &str, labels: &[String], series: &[(String, Vec<Option<f64>>)]) -> Res<()> {
    png(path, |root| bars_on(root, title, y_desc, labels, series))
}

fn bars_on(
    root: &Area<'_>,
    title: &str,
    y_desc: &str,
    labels: &[String],
    series: &[(String, Vec<Option<f64>>)],
) -> Res<()> {
    let top = series.iter().flat_map(|s| s.1.iter().flatten()).fold(0.0f64, |a, &b| a.max(b)).max(1e-9) * 1.15;
    let n = labels.len().max(1);
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0.0..top)?;
    let labels_c = labels.to_vec();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(n)
        .x_label_formatter(&|x| {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 {
                labels_c.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        })
        .y_desc(y_desc)
        .label_style(("sans-serif", 14))
        .draw()?;
    let width = 0.8 / series.len().max(1) as f64;
    for (k, (name, values)) in series.iter().enumerate() {
        let colour = PALETTE[k % PALETTE.len()];
        let rects = values.iter().enumerate().filter_map(|(i, v)| {
            v.map(|v| {
                let x0 = i as f64 - 0.4 + k as f64 * width;
                Rectangle::new([(x0, 0.0), (x0 + width * 0.9, v)], colour.filled())
            })
        });
        chart
            .draw_series(rects)?
            .label(name.as_str())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], colour.filled()));
    }
    legend(&mut chart)
}

fn paper(rs: &[&Record], path: &Path) -> Res<()> {
    let labels: Vec<String> = ["a", "b", "c", "d"].iter().map(|s| s.to_string()).collect();
    let series: Vec<(String, Vec<Option<f64>>)> = kinds(rs)
        .into_iter()
        .map(|k| {
            let v = labels
                .iter()
                .map(|l| rs.iter().find(|r| r.backend_kind == k && &r.setting == l).map(|r| r.median_ms))
                .collect();
            (k, v)
        })
        .collect();
    bars(
        path,
        "Static (a) vs animated (b) vs animated + optimized (c, d): median frame time",
        "median frame time (ms)",
        &[
            "a: static".into(),
            "b: animated, plain".into(),
            "c: cull+sort+hit buffer".into(),
            "d: default plan + shadows".into(),
        ],
        &series,
    )
}

fn peers(rs: &[&Record], path: &Path) -> Res<()> {
    // One panel per view; one bar group per caster, one bar per thread count.
    let view_of = |r: &Record| r.setting.split_once(": ").map_or(String::new(), |(v, _)| v.to_string());
    let mut views: Vec<String> = Vec::new();
    for r in rs {
        if !views.contains(&view_of(r)) {
            views.push(view_of(r));
        }
    }
    let mut threads: Vec<u64> = rs.iter().map(|r| r.x as u64).collect();
    threads.sort_unstable();
    threads.dedup();
    let panels = views.len().max(1);
    png_sized(path, (SIZE.0, 400 * panels as u32), |root| {
        for (view, area) in views.iter().zip(root.split_evenly((panels, 1))) {
            let vr: Vec<&&Record> = rs.iter().filter(|r| &view_of(r) == view).collect();
            let mut labels: Vec<String> = Vec::new();
            for r in &vr {
                if !labels.contains(&r.name) {
                    labels.push(r.name.clone());
                }
            }
            let series: Vec<(String, Vec<Option<f64>>)> = threads
                .iter()
                .map(|&t| {
                    let values = labels
                        .iter()
                        .map(|l| vr.iter().find(|r| &r.name == l && r.x as u64 == t).map(|r| r.mrays_per_s))
                        .collect();
                    (format!("{t} thread{}", if t == 1 { "" } else { "s" }), values)
                })
                .collect();
            let short: Vec<String> = labels
                .iter()
                .map(|l| {
                    l.replace(" (whole frame)", " frame")
                        .replace(" (trace only)", " trace")
                        .replace("parry3d ", "parry ")
                })
                .collect();
            let title = format!(
                "Primary rays per second, {}: same geometry, camera and threads",
                if view.is_empty() { "default" } else { view }
            );
            bars_on(&area, &title, "Mrays/s", &short, &series)?;
        }
        Ok(())
    })
}

/// Lines through (x, y) points, one series per key, optionally log-log.
fn lines(path: &Path, title: &str, (x_desc, y_desc): (&str, &str), series: &[Series], log: bool) -> Res<()> {
    png(path, |root| lines_on(root, title, (x_desc, y_desc), series, log))
}

fn lines_on(root: &Area<'_>, title: &str, (x_desc, y_desc): (&str, &str), series: &[Series], log: bool) -> Res<()> {
    let pts = series.iter().flat_map(|s| s.1.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        x0 = x0.min(p.0);
        x1 = x1.max(p.0);
        y0 = y0.min(p.1);
        y1 = y1.max(p.1);
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    let mut builder = ChartBuilder::on(root);
    builder.caption(title, ("sans-serif", 22)).margin(12).x_label_area_size(45).y_label_area_size(70);
    macro_rules! body {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).label_style(("sans-serif", 14)).draw()?;
            for (k, (name, p)) in series.iter().enumerate() {
                let colour = PALETTE[k % PALETTE.len()];
                let xy: Vec<(f64, f64)> = p.iter().map(|q| (q.0, q.1)).collect();
                chart
                    .draw_series(LineSeries::new(xy.clone(), colour.stroke_width(2)))?
                    .label(name.as_str())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
                chart.draw_series(xy.iter().map(|&q| Circle::new(q, 4, colour.filled())))?;
                chart.draw_series(
                    p.iter()
                        .filter(|q| !q.2.is_empty())
                        .map(|q| Text::new(q.2.clone(), (q.0, q.1), ("sans-serif", 13).into_font().color(&colour))),
                )?;
            }
            legend(&mut chart)?;
        }};
    }
    if log {
        let (x0, y0) = (x0.max(1e-9), y0.max(1e-9));
        body!(builder.build_cartesian_2d((x0 * 0.8..x1 * 1.25).log_scale(), (y0 * 0.8..y1 * 1.25).log_scale())?);
    } else {
        let (dx, dy) = ((x1 - x0).max(1e-9) * 0.08, (y1 - y0).max(1e-9) * 0.12);
        body!(builder.build_cartesian_2d((x0 - dx).max(0.0)..x1 + dx, (y0 - dy).max(0.0)..y1 + dy)?);
    }
    Ok(())
}

fn instances(rs: &[&Record], path: &Path) -> Res<()> {
    let mut series = Vec::new();
    for k in kinds(rs) {
        for setting in ["BVH", "sorted spheres"] {
            let p: Vec<(f64, f64, String)> = rs
                .iter()
                .filter(|r| r.backend_kind == k && r.setting == setting)
                .map(|r| (r.instances as f64, r.median_ms, String::new()))
                .collect();
            if !p.is_empty() {
                series.push((format!("{k}, {setting}"), p));
            }
        }
    }
    lines(path, "Instance scaling (log-log)", ("instances", "median frame time (ms)"), &series, true)
}

/// Splats against rays: frame time over the voxels drawn (the level sweep) and over the cars,
/// both log-log, one line per renderer.
fn splat(rs: &[&Record], path: &Path) -> Res<()> {
    let mut series = Vec::new();
    for k in kinds(rs) {
        for (key, unit) in [("level ", "one car by voxel count"), (" cars: ", "cars")] {
            for setting in ["trace", "splat", "splat (quads)"] {
                let p: Vec<(f64, f64, String)> = rs
                    .iter()
                    .filter(|r| r.backend_kind == k && r.setting == setting && r.name.contains(key))
                    .map(|r| (r.x, r.median_ms, String::new()))
                    .collect();
                if !p.is_empty() {
                    series.push((format!("{k}: {setting}, {unit}"), p));
                }
            }
        }
    }
    lines(
        path,
        "Splats against rays (log-log; x: voxels or cars)",
        ("voxels (level sweep) or cars", "median frame time (ms)"),
        &series,
        true,
    )
}

fn gi_scaling(rs: &[&Record], path: &Path) -> Res<()> {
    let ks = kinds(rs);
    let mut series: Vec<Series> = Vec::new();
    for k in &ks {
        for n in ["transformation (split)", "transformation (nearest)", "re-voxelization"] {
            let label = if ks.len() > 1 { format!("{n}, {k}") } else { n.to_string() };
            let p =
                rs.iter().filter(|r| r.name == n && r.backend_kind == *k).map(|r| (r.x, r.median_ms, String::new()));
            series.push((label, p.collect()));
        }
    }
    lines(path, "Moving cars into the GI volume (log-log)", ("moving cars", "time per frame (ms)"), &series, true)
}

/// Error against run time: one line per knob, each point labelled with its setting.
/// Prefix of the accuracy records measured on the emissive-panel room.
const PANEL: &str = "panel room: ";

/// Prefix of the accuracy records measured on the car on its ground ([`crate::bench::gi::CAR`]).
const CAR: &str = super::gi::CAR;

fn gi_accuracy(rs: &[&Record], path: &Path) -> Res<()> {
    let rs: Vec<&Record> =
        rs.iter().copied().filter(|r| ![PANEL, CAR, THICK].iter().any(|p| r.name.starts_with(p))).collect();
    accuracy_chart(&rs, "", path, "GI error against run time (box scene; bounces against the all-bounce reference)")
}

fn gi_accuracy_panel(rs: &[&Record], path: &Path) -> Res<()> {
    let rs: Vec<&Record> = rs.iter().copied().filter(|r| r.name.starts_with(PANEL)).collect();
    let title = "GI error against run time (emissive-panel room; light samples: whole frame, and pixels alone)";
    accuracy_chart(&rs, PANEL, path, title)
}

fn gi_accuracy_car(rs: &[&Record], path: &Path) -> Res<()> {
    let rs: Vec<&Record> = rs.iter().copied().filter(|r| r.name.starts_with(CAR)).collect();
    if rs.is_empty() {
        return Ok(());
    }
    accuracy_chart(&rs, CAR, path, "GI error against run time (the car on its ground, sun and sky)")
}

/// Prefix of the accuracy records measured on the thick-walled box ([`crate::bench::gi::THICK`]).
const THICK: &str = super::gi::THICK;

fn gi_accuracy_thick(rs: &[&Record], path: &Path) -> Res<()> {
    let rs: Vec<&Record> = rs.iter().copied().filter(|r| r.name.starts_with(THICK)).collect();
    if rs.is_empty() {
        return Ok(());
    }
    accuracy_chart(&rs, THICK, path, "GI error against run time (the box with thick walls, sunlit outside)")
}

/// Every knob of the accuracy records `rs` (names after `prefix`) as a curve.
fn accuracy_chart(rs: &[&Record], prefix: &str, path: &Path, title: &str) -> Res<()> {
    let knob = |r: &Record| r.name.strip_prefix(prefix).unwrap_or(&r.name).to_string();
    let mut knobs: Vec<String> = Vec::new();
    for r in rs.iter().filter(|r| !knob(r).starts_with("reference") && knob(r) != "no GI (flat sky term)") {
        if !knobs.contains(&knob(r)) {
            knobs.push(knob(r));
        }
    }
    let series: Vec<Series> = knobs
        .iter()
        .map(|k| {
            let p = rs
                .iter()
                .filter(|r| knob(r) == *k)
                .filter_map(|r| r.error.and_then(|e| e.flip).map(|f| (r.median_ms, f, format!(" {}", r.setting))))
                .collect();
            (k.to_string(), p)
        })
        .collect();
    lines(path, title, ("GI time per frame (ms)", "mean FLIP vs path-traced reference"), &series, false)
}

fn resolution(rs: &[&Record], path: &Path) -> Res<()> {
    let series: Vec<_> = kinds(rs)
        .into_iter()
        .map(|k| {
            let p = rs
                .iter()
                .filter(|r| r.backend_kind == k)
                .map(|r| (r.x / 1e6, r.median_ms, format!(" {}×{}", r.width, r.height)))
                .collect();
            (k, p)
        })
        .collect();
    lines(path, "Frame time against image size", ("megapixels", "median frame time (ms)"), &series, false)
}

fn depth(rs: &[&Record], path: &Path) -> Res<()> {
    let series: Vec<_> = kinds(rs)
        .into_iter()
        .map(|k| {
            // Coarse to fine, so the line runs along the error-versus-time curve.
            let mut by_level: Vec<&&Record> = rs.iter().filter(|r| r.backend_kind == k).collect();
            by_level.sort_by(|a, b| a.x.total_cmp(&b.x));
            let p =
                by_level.iter().map(|r| (r.median_ms, r.error.map_or(0.0, |e| e.rmse), format!(" L{}", r.x))).collect();
            (k, p)
        })
        .collect();
    lines(
        path,
        "Level of detail: image error against frame time",
        ("median frame time (ms)", "image RMSE vs full depth"),
        &series,
        false,
    )
}
