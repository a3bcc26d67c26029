//! Constants the Rust code and the WGSL shaders share, written once: every shader source
//! starts with [`prelude`], generated here from the Rust constants, and no `.wgsl` file
//! defines them itself (`tests/layout.rs` checks both).

/// The shared constants: WGSL name, WGSL type and value (as a WGSL literal).
pub fn shared() -> Vec<(&'static str, &'static str, String)> {
    let u = |v: u64| format!("{v}u");
    // Debug prints the shortest text that reads back as the same f32.
    let f = |v: f32| format!("{v:?}");
    vec![
        ("MAX_DEPTH", "u32", u(crate::svo::MAX_DEPTH as u64)),
        ("PARALLEL_RATIO", "f32", f(crate::ray::PARALLEL_RATIO)),
        ("MAX_UNIT_ORIGIN", "f32", f(crate::ray::MAX_UNIT_ORIGIN)),
        ("MOVED_SEARCH_MAX", "u32", u(crate::render::hitbuffer::MOVED_SEARCH_MAX as u64)),
        ("FIX", "f32", f(super::gi::FIX as f32)),
        ("EMIT_FIX", "f32", f(super::gi::EMIT_FIX as f32)),
        ("OUT_FIX", "f32", f(super::gi::OUT_FIX as f32)),
        ("STRIDE", "u32", u(super::gi::STRIDE as u64)),
        ("GI_BRICK", "u32", u(crate::gi::sparse::BRICK as u64)),
        ("GI_BRICK_LEVELS", "u32", u(crate::gi::sparse::BRICK_LEVELS as u64)),
        ("GI_EMPTY", "u32", u(crate::gi::sparse::EMPTY as u64)),
        ("GI_CLEARANCE", "f32", f(crate::gi::cone::CLEARANCE as f32)),
    ]
}

/// The WGSL that every shader source starts with.
pub fn prelude() -> String {
    let mut s =
        String::from("// Generated from the Rust constants (src/gpu/prelude.rs); not defined in any .wgsl file.\n");
    for (name, ty, value) in shared() {
        s += &format!("const {name}: {ty} = {value};\n");
    }
    s
}
