// Poses a crowd of cars on the GPU and writes each car's eight instances as the frame's
// tracer reads them (`Inst`), camera-relative: the twin of voxray::scene::car::car_pose, the
// scene's world transforms and voxray::render::instances::prepare_into with
// voxray::gpu::renderer::gpu_instance, so that a crowd's frame needs no per-car work on the
// host. Rust side: src/gpu/crowd.rs.
//
// Time and the eye arrive reduced on the host in f64 (the time within a lap and a door
// cycle, whole laps as distance wrapped to a wheel turn; the eye and each car's centre as two
// f32 each), so f32 here only ever holds values of a lap's size: a clip at t = 10⁶ s poses
// as one in its first minute, as on the CPU.

@group(0) @binding(0) var<uniform> crowd: CrowdFrame;
@group(0) @binding(1) var<storage, read> crowd_cars: array<CrowdCar>;
@group(0) @binding(2) var<storage, read> crowd_parts: array<CrowdPart>;
// Per slot of a car (body, wheels, doors, steering wheel): its pivot, then its axis.
@group(0) @binding(3) var<storage, read> crowd_rig: array<vec4<f32>>;
// The arc-length table at CAR_ARC_STEPS + 1 path parameters over a lap: the length wrapped
// to a wheel turn, the speed, the length of the interval to the next parameter.
@group(0) @binding(4) var<storage, read> crowd_arc: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> crowd_insts: array<Inst>;

const TAU: f32 = 6.283185307179586;

// x wrapped into [0, period).
fn wrap(x: f32, period: f32) -> f32 {
    let r = x - floor(x / period) * period;
    return select(r, 0.0, r >= period || r < 0.0);
}

struct PathPoint {
    p: vec3<f32>,
    v: vec3<f32>,
    a: vec3<f32>,
}

// Position on the figure-eight and its first and second derivatives at parameter s.
fn path(s: f32) -> PathPoint {
    let w = TAU / CAR_PATH_PERIOD;
    let sn = sin(s);
    let cs = cos(s);
    let sin2 = 2.0 * sn * cs;
    let cos2 = (cs - sn) * (cs + sn);
    var out: PathPoint;
    out.p = vec3<f32>(CAR_PATH_A * sn, 0.0, 0.5 * CAR_PATH_A * sin2);
    out.v = vec3<f32>(CAR_PATH_A * cs, 0.0, CAR_PATH_A * cos2) * w;
    out.a = vec3<f32>(-CAR_PATH_A * sn, 0.0, -2.0 * CAR_PATH_A * sin2) * (w * w);
    return out;
}

// Arc length from parameter 0 to s in [0, 2π), wrapped to a wheel turn (what the wheels'
// angle needs): cubic Hermite between the table's lengths, written as the interval's first
// length plus the part of the interval covered, so that f32 never holds a whole lap's length.
fn arc_length(s: f32) -> f32 {
    let h = TAU / f32(CAR_ARC_STEPS);
    let k = min(u32(max(floor(s / h), 0.0)), CAR_ARC_STEPS - 1u);
    let u = (s - f32(k) * h) / h;
    let a = crowd_arc[k];
    let b = crowd_arc[k + 1u];
    let u2 = u * u;
    let u3 = u2 * u;
    return a.x + (3.0 * u2 - 2.0 * u3) * a.z + (u3 - 2.0 * u2 + u) * h * a.y + (u3 - u2) * h * b.y;
}

// Door angle at time t within its cycle.
fn door_angle(t: f32) -> f32 {
    let u = wrap(t, CAR_DOOR_PERIOD) / CAR_DOOR_PERIOD;
    let opening = clamp((u - 0.25) / 0.15, 0.0, 1.0);
    let closing = clamp((u - 0.7) / 0.15, 0.0, 1.0);
    return CAR_DOOR_OPEN * (opening * opening * (3.0 - 2.0 * opening) - closing * closing * (3.0 - 2.0 * closing));
}

// The rotation about +y turning +x towards v's horizontal direction (x, y, z, w).
fn heading(v: vec3<f32>) -> vec4<f32> {
    let len = sqrt(v.x * v.x + v.z * v.z);
    if (!(len > 0.0)) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    let c = v.x / len;
    let s = -v.z / len;
    if (c >= 0.0) {
        let hc = sqrt(0.5 * (1.0 + c));
        return vec4<f32>(0.0, s / (2.0 * hc), 0.0, hc);
    }
    let hs = select(-1.0, 1.0, s >= 0.0) * sqrt(0.5 * (1.0 - c));
    return vec4<f32>(0.0, hs, 0.0, s / (2.0 * hs));
}

// Quaternion product a·b.
fn quat_mul(a: vec4<f32>, b: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(a.w * b.xyz + b.w * a.xyz + cross(a.xyz, b.xyz), a.w * b.w - dot(a.xyz, b.xyz));
}

// A unit quaternion's rotation matrix (columns).
fn quat_mat(q: vec4<f32>) -> mat3x3<f32> {
    let x2 = q.x + q.x;
    let y2 = q.y + q.y;
    let z2 = q.z + q.z;
    let xx = q.x * x2;
    let xy = q.x * y2;
    let xz = q.x * z2;
    let yy = q.y * y2;
    let yz = q.y * z2;
    let zz = q.z * z2;
    let wx = q.w * x2;
    let wy = q.w * y2;
    let wz = q.w * z2;
    return mat3x3<f32>(
        vec3<f32>(1.0 - (yy + zz), xy + wz, xz - wy),
        vec3<f32>(xy - wz, 1.0 - (xx + zz), yz + wx),
        vec3<f32>(xz + wy, yz - wx, 1.0 - (xx + yy)),
    );
}

// How far a box's farthest corner lies from its centre once mapped by m (half extents e).
fn farthest_corner(m: mat3x3<f32>, e: vec3<f32>) -> f32 {
    let a = m[0] * e.x + m[1] * e.y;
    let b = m[0] * e.x - m[1] * e.y;
    let z = m[2] * e.z;
    return sqrt(max(max(dot(z + a, z + a), dot(z - a, z - a)), max(dot(z + b, z + b), dot(z - b, z - b))));
}

// render::instances::stretch_bound: a bound on how far m stretches any vector (Gershgorin
// on the columns' dot products).
fn stretch_bound(m: mat3x3<f32>) -> f32 {
    let ab = abs(dot(m[0], m[1]));
    let ac = abs(dot(m[0], m[2]));
    let bc = abs(dot(m[1], m[2]));
    return sqrt(max(max(dot(m[0], m[0]) + ab + ac, dot(m[1], m[1]) + ab + bc), dot(m[2], m[2]) + ac + bc));
}

// Writes instance `inst` placing `part` by the camera-relative world rotation r and
// translation t.
fn write_instance(inst: u32, part: u32, r: mat3x3<f32>, t: vec3<f32>) {
    let pt = crowd_parts[part];
    let size = pt.box_centre.w;
    // World -> unit cube: the inverse (the transpose of a rotation) scaled by 1 / size.
    let m = transpose(r) * (1.0 / size);
    let shift = (-(m * t)) - pt.cube_min.xyz / size;
    let big = max(max(max(abs(m[0].x), abs(m[0].y)), max(abs(m[0].z), abs(m[1].x))),
        max(max(abs(m[1].y), abs(m[1].z)), max(max(abs(m[2].x), abs(m[2].y)), abs(m[2].z))));
    let unit = select(1.0, 1.0 / big, big > 0.0);
    let stretch = sqrt(max(max(dot(r[0], r[0]), dot(r[1], r[1])), dot(r[2], r[2])));
    let centre = r * pt.box_centre.xyz + t;
    // As the host's fill_slot: the box's farthest corner or the cells' reach, the nearer.
    let held = min(farthest_corner(r, pt.box_half.xyz), pt.box_half.w * stretch_bound(r));
    let r0 = held * (1.0 + SPHERE_PAD) + 1.5 * size * stretch * SPHERE_PAD;
    // Both radii grown by what forming the transform in f32 here can add over the host's
    // f64: a few units in the last place of the distance. The one the boxes fit...
    let far = length(centre);
    let extra = 4e-6 * (far + size);
    let radius = r0 + extra;
    // ...and the one the sphere test uses, grown first as the host grows it (gpu_sphere).
    let grown = (r0 + 4e-7 * far * far / max(r0, 1e-30) + 1e-6 * far) * (1.0 + 1e-6) + extra;
    var out: Inst;
    out.to_unit_x = vec4<f32>(m[0].x, m[1].x, m[2].x, shift.x);
    out.to_unit_y = vec4<f32>(m[0].y, m[1].y, m[2].y, shift.y);
    out.to_unit_z = vec4<f32>(m[0].z, m[1].z, m[2].z, shift.z);
    out.normal_x = vec4<f32>(m[0] * unit, 0.0);
    out.normal_y = vec4<f32>(m[1] * unit, 0.0);
    out.normal_z = vec4<f32>(m[2] * unit, 0.0);
    out.sphere = vec4<f32>(centre, grown);
    out.part = part;
    out.stretch_size = stretch * size;
    out.moved = 0u;
    out.radius = radius;
    crowd_insts[inst] = out;
}

// A child's local rotation q about a pivot, composed under the body (rb, tb) and written.
fn write_child(inst: u32, part: u32, q: vec4<f32>, pivot: vec3<f32>, rb: mat3x3<f32>, tb: vec3<f32>) {
    let rl = quat_mat(q);
    write_instance(inst, part, rb * rl, rb * (pivot - rl * pivot) + tb);
}

// Slot j (0-7: body, four wheels, two doors, steering wheel) of a car's (a | b) words.
fn slot(a: vec4<u32>, b: vec4<u32>, j: u32) -> u32 {
    if (j < 4u) {
        return a[j];
    }
    return b[j - 4u];
}

// One invocation per car: its pose at the frame's time, its eight instances written.
@compute @workgroup_size(64)
fn crowd_pose_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * 65535u * 64u;
    if (i >= crowd.cars) {
        return;
    }
    let car = crowd_cars[i];
    // The time within the lap; a lap completed by the two offsets carries into the distance.
    let lap_t = crowd.eye_hi.w + car.origin_hi.w;
    let carry = select(0.0, 1.0, lap_t >= CAR_PATH_PERIOD);
    let s = (lap_t - carry * CAR_PATH_PERIOD) * (TAU / CAR_PATH_PERIOD);
    let pp = path(s);
    let speed = length(pp.v);
    let curvature = (pp.a.x * pp.v.z - pp.v.x * pp.a.z) / (speed * speed * speed);
    let steer = clamp(atan(CAR_WHEELBASE * curvature), -CAR_STEER_MAX, CAR_STEER_MAX);
    let distance = car.spin + crowd.spin + carry * crowd.lap_spin + arc_length(s);
    let circumference = TAU * CAR_WHEEL_RADIUS;
    let spin = -(wrap(distance, circumference) / CAR_WHEEL_RADIUS);
    // The centre relative to the eye, from the two halves of each (the large parts cancel).
    let origin = (car.origin_hi.xyz - crowd.eye_hi.xyz) + (car.origin_lo.xyz - crowd.eye_lo.xyz);
    var tb = origin;
    var qb = vec4<f32>(0.0, 0.0, 0.0, 1.0);
    if (car.travel != 0u) {
        tb = origin + pp.p;
        qb = normalize(heading(pp.v));
    }
    let rb = quat_mat(qb);
    write_instance(car.inst_a.x, car.part_a.x, rb, tb);
    // Wheels: spin about the axle; the front two also steer about +y.
    let ss = sin(0.5 * spin);
    let cs = cos(0.5 * spin);
    let steer_q = vec4<f32>(0.0, sin(0.5 * steer), 0.0, cos(0.5 * steer));
    for (var k = 0u; k < 4u; k++) {
        let pivot = crowd_rig[2u * (k + 1u)].xyz;
        let axle = crowd_rig[2u * (k + 1u) + 1u].xyz;
        var q = vec4<f32>(axle * ss, cs);
        if (k < 2u) {
            q = quat_mul(steer_q, q);
        }
        write_child(slot(car.inst_a, car.inst_b, k + 1u), slot(car.part_a, car.part_b, k + 1u), normalize(q), pivot,
            rb, tb);
    }
    // Doors about their hinges.
    let half_door = 0.5 * door_angle(crowd.eye_lo.w + car.origin_lo.w);
    for (var k = 0u; k < 2u; k++) {
        let pivot = crowd_rig[2u * (k + 5u)].xyz;
        let axis = normalize(crowd_rig[2u * (k + 5u) + 1u].xyz);
        let q = vec4<f32>(axis * sin(half_door), cos(half_door));
        write_child(car.inst_b[k + 1u], car.part_b[k + 1u], normalize(q), pivot, rb, tb);
    }
    // The steering wheel turns with the front wheels, the other way round, faster.
    let pivot = crowd_rig[14].xyz;
    let axis = normalize(crowd_rig[15].xyz);
    let half_turn = 0.5 * (-steer * CAR_STEERING_RATIO);
    write_child(car.inst_b.w, car.part_b.w, normalize(vec4<f32>(axis * sin(half_turn), cos(half_turn))), pivot, rb,
        tb);
}
