//! Triangulating an OBJ polygon face by ear clipping, so that a concave face keeps its
//! notches (a fan from the first vertex fills them).
//!
//! The polygon is projected onto the plane of its Newell normal (dropping the normal's
//! largest axis) and ears are cut from the 2-D outline: a convex corner whose triangle holds
//! no other vertex of the remaining outline. Each triangle keeps the face's vertex order, so
//! its winding (and so its normal) is the face's.

use glam::{DVec2, DVec3, Vec3};

/// Largest face that is ear-clipped (the clipping is quadratic in the vertex count); larger
/// faces are fanned and counted in [`Triangulated::fanned`].
pub const MAX_EAR_CLIPPED: usize = 4096;

/// The triangles of one face, as indices into its vertex list.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Triangulated {
    /// Triangles (vertex positions within the face), in the face's winding.
    pub triangles: Vec<[usize; 3]>,
    /// The face could not be ear-clipped (it crosses itself, is flat as a line, or has more
    /// than [`MAX_EAR_CLIPPED`] vertices) and was fanned from where the clipping stopped.
    pub fanned: bool,
}

/// Triangulates the polygon `points` (three or more vertices, in face order).
pub fn triangulate(points: &[Vec3]) -> Triangulated {
    let n = points.len();
    if n < 3 {
        return Triangulated::default();
    }
    if n == 3 {
        return Triangulated { triangles: vec![[0, 1, 2]], fanned: false };
    }
    let fan = |rest: &[usize]| (1..rest.len() - 1).map(|k| [rest[0], rest[k], rest[k + 1]]).collect::<Vec<_>>();
    let all: Vec<usize> = (0..n).collect();
    if n > MAX_EAR_CLIPPED {
        return Triangulated { triangles: fan(&all), fanned: true };
    }
    // Newell's normal: robust for non-planar and concave outlines; its length is twice the
    // projected area.
    let p: Vec<DVec3> = points.iter().map(|v| v.as_dvec3()).collect();
    let centre = p.iter().copied().sum::<DVec3>() / n as f64;
    let mut normal = DVec3::ZERO;
    for i in 0..n {
        let (a, b) = (p[i] - centre, p[(i + 1) % n] - centre);
        normal += DVec3::new((a.y - b.y) * (a.z + b.z), (a.z - b.z) * (a.x + b.x), (a.x - b.x) * (a.y + b.y));
    }
    if !normal.is_finite() || normal.length_squared() == 0.0 {
        return Triangulated { triangles: fan(&all), fanned: true };
    }
    // Drop the normal's largest axis; swap the other two where that axis is negative so that
    // the outline runs counter-clockwise in 2-D.
    let axis = normal.abs().max_position();
    let (u, v) = match axis {
        0 => (1, 2),
        1 => (2, 0),
        _ => (0, 1),
    };
    let flip = normal[axis] < 0.0;
    let q: Vec<DVec2> = p
        .iter()
        .map(|x| {
            let d = *x - centre;
            if flip {
                DVec2::new(d[v], d[u])
            } else {
                DVec2::new(d[u], d[v])
            }
        })
        .collect();
    let cross = |a: DVec2, b: DVec2, c: DVec2| (b - a).perp_dot(c - a);
    let mut ring = all;
    let mut triangles = Vec::with_capacity(n - 2);
    let mut i = 0;
    // Corners tried since the last ear was cut: a whole lap without one means no ear is left.
    let mut tried = 0;
    while ring.len() > 3 {
        let m = ring.len();
        let (a, b, c) = (ring[(i + m - 1) % m], ring[i % m], ring[(i + 1) % m]);
        let (qa, qb, qc) = (q[a], q[b], q[c]);
        let convex = cross(qa, qb, qc) > 0.0;
        let ear = convex
            && ring.iter().all(|&k| {
                if k == a || k == b || k == c {
                    return true;
                }
                // Outside the closed triangle (a vertex on its edge blocks it).
                let x = q[k];
                !(cross(qa, qb, x) >= 0.0 && cross(qb, qc, x) >= 0.0 && cross(qc, qa, x) >= 0.0)
            });
        if ear {
            triangles.push([a, b, c]);
            ring.remove(i % m);
            tried = 0;
            // Stay at the same place: the corner before it may have become an ear.
            i = (i % m + m - 2) % (m - 1);
            continue;
        }
        tried += 1;
        if tried > m {
            // Self-crossing or degenerate outline: fan what is left.
            triangles.extend(fan(&ring));
            return Triangulated { triangles, fanned: true };
        }
        i = (i + 1) % m;
    }
    triangles.push([ring[0], ring[1], ring[2]]);
    Triangulated { triangles, fanned: false }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(points: &[Vec3], t: &Triangulated) -> f64 {
        t.triangles
            .iter()
            .map(|&[a, b, c]| {
                let (a, b, c) = (points[a].as_dvec3(), points[b].as_dvec3(), points[c].as_dvec3());
                (b - a).cross(c - a).length() * 0.5
            })
            .sum()
    }

    /// The square 4×4 with a notch down to (2, 1) in its top edge, starting at the corner
    /// from which a fan covers the notch: area 10, a fan's triangles add up to 22.
    fn notched() -> Vec<Vec3> {
        [[4.0, 4.0], [2.0, 1.0], [0.0, 4.0], [0.0, 0.0], [4.0, 0.0]].map(|[x, y]| Vec3::new(x, y, 0.0)).to_vec()
    }

    #[test]
    fn a_notch_stays_open() {
        let p = notched();
        let t = triangulate(&p);
        assert!(!t.fanned);
        assert_eq!(t.triangles.len(), 3);
        assert!((area(&p, &t) - 10.0).abs() < 1e-9, "area {}", area(&p, &t));
        // Every triangle keeps the face's winding (+z normal).
        for &[a, b, c] in &t.triangles {
            assert!((p[b] - p[a]).cross(p[c] - p[a]).z > 0.0);
        }
    }

    #[test]
    fn winding_and_plane_do_not_matter() {
        // Reversed order (normal −z) and the same outline rotated into the x = 3 plane.
        let mut p = notched();
        p.reverse();
        let t = triangulate(&p);
        assert!((area(&p, &t) - 10.0).abs() < 1e-9);
        for &[a, b, c] in &t.triangles {
            assert!((p[b] - p[a]).cross(p[c] - p[a]).z < 0.0);
        }
        let side: Vec<Vec3> = notched().iter().map(|v| Vec3::new(3.0, v.x, v.y)).collect();
        assert!((area(&side, &triangulate(&side)) - 10.0).abs() < 1e-9);
    }

    #[test]
    fn comb_with_many_teeth() {
        // A 40×1 spine with 20 teeth 1 wide and 3 high on top (area 100), counter-clockwise:
        // along the bottom, then leftwards over every tooth and gap.
        let mut p = vec![Vec3::new(0.0, 0.0, 0.0), Vec3::new(40.0, 0.0, 0.0)];
        for k in (0..20).rev() {
            let (x0, x1) = (2.0 * k as f32 + 1.0, 2.0 * k as f32 + 2.0);
            p.extend([
                Vec3::new(x1, 4.0, 0.0),
                Vec3::new(x0, 4.0, 0.0),
                Vec3::new(x0, 1.0, 0.0),
                Vec3::new(x0 - 1.0, 1.0, 0.0),
            ]);
        }
        let t = triangulate(&p);
        assert!(!t.fanned);
        assert_eq!(t.triangles.len(), p.len() - 2);
        assert!((area(&p, &t) - 100.0).abs() < 1e-6, "area {}", area(&p, &t));
    }

    #[test]
    fn bad_outlines_are_fanned_not_lost() {
        // A bow tie (crosses itself) and a polygon flat as a line.
        let bow = [[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]].map(|[x, y]| Vec3::new(x, y, 0.0));
        let t = triangulate(&bow);
        assert_eq!(t.triangles.len(), 2);
        let line = [0.0, 1.0, 2.0, 3.0].map(|x| Vec3::new(x, 0.0, 0.0));
        let t = triangulate(&line);
        assert!(t.fanned);
        assert_eq!(t.triangles.len(), 2);
        assert_eq!(triangulate(&line[..2]).triangles.len(), 0);
    }
}
