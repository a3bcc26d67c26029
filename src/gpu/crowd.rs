//! Posing a crowd of cars on the GPU: one pass (`crowd_pose_main` in `wgsl/pose.wgsl`)
//! evaluates every car's clip at the frame's time and writes its eight instances straight
//! into the tracer's instance buffer, camera-relative, as the host's posing, transform
//! update and preparation would ([`crate::scene::car::car_pose`], [`Scene::update`],
//! [`crate::render::instances::prepare_into`]). A 10 000-car frame then asks of the host a
//! uniform write instead of posing, composing and converting tens of thousands of
//! transforms (docs/benchmarks.md, "Where goal 4 stands on the GPU").
//!
//! The host reduces what f32 cannot hold, once per crowd and once per frame, in f64: the
//! time within a lap and a door cycle, whole laps as distance wrapped to a wheel turn, and
//! the eye and every car's centre split into two f32 each whose difference the shader takes
//! half by half. The shader's transforms then agree with the host's to 10⁻⁵ of an entry or
//! better (f32 sines, cosines and arctangents; 2-3·10⁻⁵ for the steering wheel, which turns
//! fifteen times the steering angle), and its spheres are grown to hold what the host's hold
//! (tested in this module against the host's instances).

use super::context::{GpuContext, GpuError};
use super::layout::{GpuCrowdCar, GpuCrowdFrame, GpuCrowdPart};
use crate::scene::car::{arc_table, lap_length, wrap, Car, DOOR_PERIOD, PATH_PERIOD};
use crate::scene::Scene;
use glam::DVec3;
use std::sync::Arc;

/// Invocations per workgroup of `crowd_pose_main` (one car each).
const GROUP: u32 = 64;

/// The shader source: the prelude, the shared structs and the pass.
pub fn pose_source() -> String {
    [&super::prelude::prelude(), include_str!("../../wgsl/shared/layout.wgsl"), include_str!("../../wgsl/pose.wgsl")]
        .join("\n")
}

/// A crowd of cars the GPU poses each frame; made once for a scene's cars at a level of
/// detail (the spheres hold what rays traced to that level can hit).
pub struct GpuCrowd {
    ctx: Arc<GpuContext>,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    frame: wgpu::Buffer,
    cars: wgpu::Buffer,
    parts: wgpu::Buffer,
    rig: wgpu::Buffer,
    arc: wgpu::Buffer,
    count: u32,
    /// One more than the highest instance a car places: the rows the instance buffer needs.
    rows: usize,
    /// The scene it was made for: its number, part edits and instance count.
    made_for: (u64, u64, usize),
    /// The bind group and the instance buffer it names.
    bind: Option<(wgpu::BindGroup, wgpu::Buffer)>,
    /// The level of detail the spheres are for.
    level: u32,
    /// The scene's instances no car places (a ground): the host prepares them.
    statics: Vec<u32>,
    /// The instance tree: built once over the instances as the scene held them when the
    /// crowd was made; refitted on the GPU each frame.
    bvh: crate::render::bvh::Bvh,
    refit: super::refit::GpuRefit,
    /// Tells crowds apart (a renderer uploads a crowd's tree once).
    id: u64,
}

/// `v` as two f32 whose sum is `v` to about 2⁻⁴⁸ of it: the larger, then what it left.
fn split(v: DVec3) -> ([f32; 3], [f32; 3]) {
    let hi = v.as_vec3();
    let lo = (v - hi.as_dvec3()).as_vec3();
    (hi.to_array(), lo.to_array())
}

/// The distance of `laps` whole laps wrapped to one wheel turn (the wheels' angle needs only
/// that), in f64.
fn lap_spin(laps: f64) -> f32 {
    wrap(laps * lap_length(), wheel_turn()) as f32
}

/// A wheel's circumference (m).
fn wheel_turn() -> f64 {
    std::f64::consts::TAU * crate::model::car::WHEEL_RADIUS as f64
}

/// A car's record, refused when its instances are not a car's: eight existing instances,
/// the body without a parent and the other seven its children.
fn car_record(scene: &Scene, k: usize, car: &Car) -> Result<GpuCrowdCar, GpuError> {
    let ids = car.instances();
    let inst = scene.instances();
    let mut parts = [0u32; 8];
    for (slot, (&i, part)) in ids.iter().zip(&mut parts).enumerate() {
        let Some(record) = inst.get(i) else {
            return Err(GpuError::Crowd(format!("car {k}: instance {i} does not exist")));
        };
        let parent_ok = if slot == 0 { record.parent.is_none() } else { record.parent == Some(car.body) };
        if !parent_ok {
            return Err(GpuError::Crowd(format!(
                "car {k}: instance {i} is not placed as a car's (the body has no parent, the rest are its children)"
            )));
        }
        *part = record.part as u32;
    }
    let (hi, lo) = split(car.origin);
    let laps = (car.phase / PATH_PERIOD).floor();
    let id = |v: &[usize]| [v[0] as u32, v[1] as u32, v[2] as u32, v[3] as u32];
    Ok(GpuCrowdCar {
        origin_hi: [hi[0], hi[1], hi[2], wrap(car.phase, PATH_PERIOD) as f32],
        origin_lo: [lo[0], lo[1], lo[2], wrap(car.phase, DOOR_PERIOD) as f32],
        spin: lap_spin(laps),
        travel: car.travel as u32,
        pad0: 0,
        pad1: 0,
        inst_a: id(&ids[..4]),
        inst_b: id(&ids[4..]),
        part_a: [parts[0], parts[1], parts[2], parts[3]],
        part_b: [parts[4], parts[5], parts[6], parts[7]],
    })
}

/// Per instance, its world sphere as the scene holds it now (prepared for an eye at the
/// origin): the crowd's tree is built over them. Its splits then part the cars by where they
/// stand and each car's parts by where they sit in it; as the cars drive, refitted boxes
/// grow apart little (docs/benchmarks.md, step 89: 0.33 octrees entered per ray at the pose
/// it was built for, 0.35-0.36 half a lap later, against 0.51-0.53 for a tree built over
/// the spheres each car's figure-eight holds).
fn build_spheres(scene: &Scene, max_level: u32) -> Vec<(DVec3, f64)> {
    let mut prepared = Vec::new();
    crate::render::instances::prepare_into(scene, DVec3::ZERO, true, max_level, &mut prepared);
    prepared.iter().map(|p| (p.centre, p.radius)).collect()
}

impl GpuCrowd {
    /// The crowd of `cars` in `scene`, for rays traced down to `max_level`; its instance
    /// tree is built over the scene's transforms as they are now (after
    /// [`Scene::update`]: [`crate::scene::stage_cars`] leaves them so). Refused when a car's
    /// instances are not a car's ([`crate::scene::car::add_car`] places them so), when two
    /// cars name the same instance, or when a buffer would pass the device's limits.
    pub fn new(ctx: Arc<GpuContext>, scene: &Scene, cars: &[Car], max_level: u32) -> Result<GpuCrowd, GpuError> {
        let records = cars.iter().enumerate().map(|(k, c)| car_record(scene, k, c)).collect::<Result<Vec<_>, _>>()?;
        let rows = cars.iter().flat_map(|c| c.instances()).max().map_or(0, |m| m + 1);
        let parts: Vec<GpuCrowdPart> = crate::render::instances::part_boxes(scene, max_level)
            .into_iter()
            .zip(&scene.parts)
            .map(|(b, svo)| {
                let (c, e, min) = (b.centre.as_vec3(), b.half.as_vec3(), svo.bounds.min);
                GpuCrowdPart {
                    box_centre: [c.x, c.y, c.z, svo.bounds.size],
                    box_half: [e.x, e.y, e.z, b.reach as f32],
                    cube_min: [min.x, min.y, min.z, 0.0],
                }
            })
            .collect();
        let rig: Vec<[f32; 4]> =
            crate::model::car::rig().iter().flat_map(|(p, a)| [[p.x, p.y, p.z, 0.0], [a.x, a.y, a.z, 0.0]]).collect();
        // Lengths wrapped to a wheel turn, with each interval's own length: f32 never holds a
        // lap's length (60 m: a wheel's angle off by 10⁻⁵).
        let table = arc_table();
        let arc: Vec<[f32; 4]> = table
            .iter()
            .enumerate()
            .map(|(k, &(l, v))| {
                let next = table.get(k + 1).map_or(l, |n| n.0);
                [wrap(l, wheel_turn()) as f32, v as f32, (next - l) as f32, 0.0]
            })
            .collect();
        ctx.check_binding("the crowd's cars", std::mem::size_of_val(&records[..]) as u64)?;
        let n = scene.instances().len();
        let mut placed = vec![false; n];
        for (k, car) in cars.iter().enumerate() {
            for i in car.instances() {
                // Two cars writing one row would race on the GPU.
                if std::mem::replace(&mut placed[i], true) {
                    return Err(GpuError::Crowd(format!("car {k}: instance {i} is placed by another car too")));
                }
            }
        }
        let statics: Vec<u32> = (0..n).filter(|&i| !placed[i]).map(|i| i as u32).collect();
        let bvh = crate::render::bvh::Bvh::build_with(&build_spheres(scene, max_level), false);
        let refit = super::refit::GpuRefit::new(&ctx, &bvh)?;
        ctx.check_binding("the crowd's instances", (rows * std::mem::size_of::<super::layout::GpuInstance>()) as u64)?;
        use super::context::{buffer_entry, BufferKind};
        let (pipeline, layout) = ctx.compute_pass(
            "crowd pose",
            pose_source(),
            "crowd_pose_main",
            &[
                buffer_entry(0, BufferKind::Uniform, None),
                buffer_entry(1, BufferKind::Read, None),
                buffer_entry(2, BufferKind::Read, None),
                buffer_entry(3, BufferKind::Read, None),
                buffer_entry(4, BufferKind::Read, None),
                buffer_entry(5, BufferKind::Write, None),
            ],
        );
        let storage = |label, bytes: &[u8]| {
            // Bindings must not be empty.
            let padded = if bytes.is_empty() { &[0u8; 16][..] } else { bytes };
            ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: padded,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let cars_buf = storage("crowd cars", bytemuck::cast_slice(&records));
        let parts_buf = storage("crowd parts", bytemuck::cast_slice(&parts));
        let rig_buf = storage("crowd rig", bytemuck::cast_slice(&rig));
        let arc_buf = storage("crowd arc table", bytemuck::cast_slice(&arc));
        let frame = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("crowd frame"),
            size: std::mem::size_of::<GpuCrowdFrame>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(GpuCrowd {
            pipeline,
            layout,
            frame,
            cars: cars_buf,
            parts: parts_buf,
            rig: rig_buf,
            arc: arc_buf,
            count: records.len() as u32,
            rows,
            made_for: (scene.id(), scene.part_edits(), scene.instances().len()),
            bind: None,
            level: max_level,
            statics,
            bvh,
            refit,
            id: {
                static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
                NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
            },
            ctx,
        })
    }

    /// Rows the instance buffer must hold (one more than the highest instance a car places).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Cars posed.
    pub fn cars(&self) -> usize {
        self.count as usize
    }

    /// The level of detail its spheres hold (frames must be traced to it).
    pub fn level(&self) -> u32 {
        self.level
    }

    /// The scene's instances no car places, ascending: the host prepares them.
    pub fn statics(&self) -> &[u32] {
        &self.statics
    }

    /// The instance tree (its topology: the boxes are refitted on the GPU each frame).
    pub fn bvh(&self) -> &crate::render::bvh::Bvh {
        &self.bvh
    }

    /// Tells crowds apart.
    pub fn id(&self) -> u64 {
        self.id
    }

    /// Encodes the refit of the tree's boxes in `nodes` (its links in place) from the
    /// spheres in `insts`, once the cars are posed there (`timestamps`: written by its pass).
    pub fn encode_refit(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        insts: &wgpu::Buffer,
        nodes: &wgpu::Buffer,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<(), GpuError> {
        self.refit.encode(&self.ctx, enc, insts, nodes, timestamps)
    }

    /// The frame's uniforms for time `t` and the eye.
    fn frame(&self, t: f64, eye: DVec3) -> GpuCrowdFrame {
        let (hi, lo) = split(eye);
        GpuCrowdFrame {
            eye_hi: [hi[0], hi[1], hi[2], wrap(t, PATH_PERIOD) as f32],
            eye_lo: [lo[0], lo[1], lo[2], wrap(t, DOOR_PERIOD) as f32],
            spin: lap_spin((t / PATH_PERIOD).floor()),
            lap_spin: lap_spin(1.0),
            cars: self.count,
            pad: 0,
        }
    }

    /// Encodes the pass that poses every car at time `t` and writes its instances, relative
    /// to `eye`, into their rows of `insts` (a buffer of [`super::layout::GpuInstance`] with
    /// at least [`GpuCrowd::rows`] rows; the others are left as they are). Refused when
    /// `scene` is not the one the crowd was made for as it was then (another scene, parts
    /// edited, instances added), when t or the eye is not finite, or `insts` is too small.
    /// `timestamps`: written by its pass (which runs even without cars, so that they are).
    pub fn encode(
        &mut self,
        scene: &Scene,
        enc: &mut wgpu::CommandEncoder,
        t: f64,
        eye: DVec3,
        insts: &wgpu::Buffer,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<(), GpuError> {
        if (scene.id(), scene.part_edits(), scene.instances().len()) != self.made_for {
            return Err(GpuError::Crowd("the scene changed since the crowd was made for it".into()));
        }
        if !t.is_finite() || !eye.is_finite() {
            return Err(GpuError::Crowd(format!("time {t} or eye {eye} is not finite")));
        }
        let need = (self.rows * std::mem::size_of::<super::layout::GpuInstance>()) as u64;
        if insts.size() < need {
            return Err(GpuError::Crowd(format!("the instance buffer holds {} bytes, {need} needed", insts.size())));
        }
        self.ctx.queue.write_buffer(&self.frame, 0, bytemuck::bytes_of(&self.frame(t, eye)));
        if self.bind.as_ref().is_none_or(|(_, b)| b != insts) {
            let group = self.ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("crowd pose"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: self.frame.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: self.cars.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: self.parts.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: self.rig.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 4, resource: self.arc.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 5, resource: insts.as_entire_binding() },
                ],
            });
            self.bind = Some((group, insts.clone()));
        }
        if let Some((group, _)) = &self.bind {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("crowd pose"),
                timestamp_writes: timestamps,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, group, &[]);
            let groups = self.count.div_ceil(GROUP);
            if groups > 0 {
                pass.dispatch_workgroups(groups.min(65_535), groups.div_ceil(65_535), 1);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::layout::GpuInstance;
    use crate::render::instances::prepare_into;
    use crate::scene::car::pose_all;

    use crate::gpu::context::test_context as context;

    /// The built-in car's parts at depth 6 (each a few thousand voxels).
    fn car_parts() -> Vec<Arc<crate::svo::Svo>> {
        let mesh = crate::model::car::mesh();
        crate::pipeline::build_parts(&mesh, crate::voxelize::Resolution::Depth(6)).expect("parts")
    }

    /// The instance buffer after the crowd's pass, every row first filled with `fill`.
    fn posed_on_gpu(
        ctx: &Arc<GpuContext>,
        crowd: &mut GpuCrowd,
        scene: &Scene,
        t: f64,
        eye: DVec3,
        fill: GpuInstance,
    ) -> Vec<GpuInstance> {
        let rows = vec![fill; scene.instances().len()];
        let insts = ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("insts"),
            contents: bytemuck::cast_slice(&rows),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        });
        let read = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("insts read"),
            size: insts.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        crowd.encode(scene, &mut enc, t, eye, &insts, None).expect("encode");
        enc.copy_buffer_to_buffer(&insts, 0, &read, 0, insts.size());
        ctx.queue.submit([enc.finish()]);
        crate::gpu::renderer::read(ctx, &read).expect("read back")
    }

    /// The largest difference between two rows.
    fn off(a: [f32; 4], b: [f32; 4]) -> f64 {
        a.iter().zip(b).map(|(x, y)| (*x as f64 - y as f64).abs()).fold(0.0, f64::max)
    }

    /// Every car instance the GPU writes is the host's (its pose, update, preparation and
    /// conversion) to a few units in the last place, and its sphere holds the host's; at
    /// early and late times (10⁶ s), near and far eyes, with cars that drive and cars that
    /// stay; rows that are not a car's are left alone.
    #[test]
    fn the_gpu_poses_a_crowd_as_the_host_does() {
        let Some(ctx) = context() else { return };
        let parts = car_parts();
        let mut st = crate::scene::stage_cars(&parts, 9, true, true).expect("stage");
        // Three cars stay in place; one sits a million units away.
        for k in [2, 5, 7] {
            st.cars[k].travel = false;
        }
        st.cars[4].origin += DVec3::new(1e6 + 0.123_456_789, 0.0, -3e5 - 0.987_654_321);
        let level = 5;
        let mut crowd = GpuCrowd::new(ctx.clone(), &st.scene, &st.cars, level).expect("crowd");
        assert_eq!(crowd.rows(), 72);
        let fill = GpuInstance { part: 99, ..GpuInstance::default() };
        let mut worst = [0.0f64; 4];
        for (t, eye) in [
            (0.0, DVec3::new(10.0, 6.0, -30.0)),
            (3.7, DVec3::new(-4.0, 2.0, 12.0)),
            (1e6 + 0.3, DVec3::new(1e6 - 20.321_7, 5.0, -3e5 + 9.041_3)),
            (-17.25, DVec3::new(40.0, 30.0, 50.0)),
        ] {
            pose_all(&mut st.scene, &st.cars, t).expect("pose");
            st.scene.update().expect("update");
            let mut prepared = Vec::new();
            prepare_into(&st.scene, eye, true, level, &mut prepared);
            let gpu = posed_on_gpu(&ctx, &mut crowd, &st.scene, t, eye, fill);
            for (i, (g, p)) in gpu.iter().zip(&prepared).enumerate() {
                if st.cars.iter().all(|c| !c.instances().contains(&i)) {
                    assert_eq!(g, &fill, "row {i} (the ground) was written");
                    continue;
                }
                let h = crate::gpu::renderer::gpu_instance(&st.scene, p, false);
                assert_eq!((g.part, g.moved), (h.part, h.moved), "instance {i}");
                let size = st.scene.parts[p.part].bounds.size as f64;
                // Linear entries are about 1 / size, translations about distance / size.
                let lin = 1.0 / size;
                let far = (p.centre.length() + size) / size;
                let (gr, hr) = ([g.to_unit_x, g.to_unit_y, g.to_unit_z], [h.to_unit_x, h.to_unit_y, h.to_unit_z]);
                let entry =
                    |j: usize| gr.iter().zip(&hr).map(|(a, b)| (a[j] as f64 - b[j] as f64).abs()).fold(0.0, f64::max);
                let linear = (0..3).map(entry).fold(0.0, f64::max) / lin;
                let translation = entry(3) / far;
                let normals = [off(g.normal_x, h.normal_x), off(g.normal_y, h.normal_y), off(g.normal_z, h.normal_z)]
                    .iter()
                    .copied()
                    .fold(0.0, f64::max);
                let (cg, ch) = (DVec3::new(g.sphere[0] as f64, g.sphere[1] as f64, g.sphere[2] as f64), {
                    DVec3::new(h.sphere[0] as f64, h.sphere[1] as f64, h.sphere[2] as f64)
                });
                let (rg, rh) = (g.sphere[3] as f64, h.sphere[3] as f64);
                assert!(
                    (cg - ch).length() + rh <= rg,
                    "instance {i} at t = {t}: the GPU's sphere {:?} does not hold the host's {:?}",
                    g.sphere,
                    h.sphere
                );
                let grown = (rg - rh) / (p.centre.length() + size);
                // The radius the BVH's boxes fit holds the host's too.
                assert!((cg - ch).length() + h.radius as f64 <= g.radius as f64, "instance {i} at t = {t}: radius");
                assert!(
                    g.radius <= h.radius * 1.001 + 1e-5 * (p.centre.length() + size) as f32,
                    "instance {i}: radius"
                );
                assert!(grown < 2e-5, "instance {i} at t = {t}: sphere grown by {grown} of its distance");
                let stretch = (g.stretch_size as f64 - h.stretch_size as f64).abs() / h.stretch_size as f64;
                for (w, v) in worst.iter_mut().zip([linear, translation, normals, stretch]) {
                    *w = w.max(v);
                }
            }
        }
        eprintln!(
            "largest differences: linear {:.1e}, translation {:.1e}, normals {:.1e}, stretch {:.1e}",
            worst[0], worst[1], worst[2], worst[3]
        );
        // f32 sines, cosines and arctangents are good to about 10⁻⁶ rad, and the steering wheel
        // turns fifteen times the wheels' steering angle: 2-3·10⁻⁵ of its entries on lavapipe,
        // the other parts under 10⁻⁵ (a wheel 0.35 m across moves by micrometres).
        assert!(worst[..3].iter().all(|&w| w < 6e-5) && worst[3] < 1e-6, "{worst:?}");
    }
}
