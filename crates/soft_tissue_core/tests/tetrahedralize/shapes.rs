//! Closed triangle surfaces with closed-form volumes: grid spheres, ellipsoids and tori, an
//! L-shaped prism, and pieces joined into one surface.

use std::f64::consts::PI;

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::io::SurfaceMesh;

/// A closed grid surface: `f(u, v)` over `nu` x `nv` cells, periodic in `u`; `v` periodic
/// too (torus) or ending at two poles (sphere).
pub fn grid(nu: usize, nv: usize, periodic_v: bool, f: impl Fn(f64, f64) -> Vec3) -> SurfaceMesh {
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    let rows = if periodic_v { nv } else { nv - 1 };
    for j in 0..rows {
        let v = if periodic_v {
            j as f64 / nv as f64
        } else {
            (j + 1) as f64 / nv as f64
        };
        for i in 0..nu {
            positions.push(f(i as f64 / nu as f64, v));
        }
    }
    let at = |i: usize, j: usize| (j * nu + i % nu) as u32;
    let ring_pairs = if periodic_v { rows } else { rows - 1 };
    for j in 0..ring_pairs {
        let jn = (j + 1) % rows;
        for i in 0..nu {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, jn), at(i, jn));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    if !periodic_v {
        let south = positions.len() as u32;
        positions.push(f(0.0, 0.0));
        let north = positions.len() as u32;
        positions.push(f(0.0, 1.0));
        for i in 0..nu {
            triangles.push([south, at(i + 1, 0), at(i, 0)]);
            triangles.push([north, at(i, rows - 1), at(i + 1, rows - 1)]);
        }
    }
    SurfaceMesh {
        positions,
        triangles,
    }
}

pub fn sphere(r: f64) -> SurfaceMesh {
    grid(48, 24, false, |u, v| {
        let (t, p) = (2.0 * PI * u, PI * v);
        Vec3::new(r * p.sin() * t.cos(), r * p.sin() * t.sin(), -r * p.cos())
    })
}

/// An ellipsoid with semi-axes `a`, `b`, `c`: flat (`c` small), its rim curves as sharply as
/// a liver's edge.
pub fn ellipsoid(a: f64, b: f64, c: f64) -> SurfaceMesh {
    grid(96, 48, false, |u, v| {
        let (t, p) = (2.0 * PI * u, PI * v);
        Vec3::new(a * p.sin() * t.cos(), b * p.sin() * t.sin(), -c * p.cos())
    })
}

pub fn torus(big: f64, small: f64) -> SurfaceMesh {
    grid(64, 24, true, |u, v| {
        let (t, p) = (2.0 * PI * u, 2.0 * PI * v);
        let rho = big + small * p.cos();
        Vec3::new(rho * t.cos(), rho * t.sin(), small * p.sin())
    })
}

/// An L-shaped prism: the L of two unit squares on a 2 x 2 square's corner removed, `depth`
/// deep, each side face split into a fine grid so its triangles are not slivers.
pub fn l_prism(depth: f64) -> SurfaceMesh {
    // The L polygon, counter-clockwise: (0,0) (2,0) (2,1) (1,1) (1,2) (0,2).
    let outline: [(f64, f64); 6] = [
        (0.0, 0.0),
        (2.0, 0.0),
        (2.0, 1.0),
        (1.0, 1.0),
        (1.0, 2.0),
        (0.0, 2.0),
    ];
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    let n = 8; // subdivisions per unit length
    // Caps: the L as three unit squares, each an n x n grid, at z = 0 (facing -z) and
    // z = depth (facing +z).
    for (z, up) in [(0.0, false), (depth, true)] {
        for (ox, oy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)] {
            let base = positions.len() as u32;
            for j in 0..=n {
                for i in 0..=n {
                    positions.push(Vec3::new(
                        ox + i as f64 / n as f64,
                        oy + j as f64 / n as f64,
                        z,
                    ));
                }
            }
            let at = |i: u32, j: u32| base + j * (n as u32 + 1) + i;
            for j in 0..n as u32 {
                for i in 0..n as u32 {
                    let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                    if up {
                        triangles.push([a, b, c]);
                        triangles.push([a, c, d]);
                    } else {
                        triangles.push([a, c, b]);
                        triangles.push([a, d, c]);
                    }
                }
            }
        }
    }
    // Sides: each outline edge extruded, facing out (the outline runs counter-clockwise).
    let layers = (depth * n as f64).ceil() as u32;
    for k in 0..outline.len() {
        let (x0, y0) = outline[k];
        let (x1, y1) = outline[(k + 1) % outline.len()];
        let len = (x1 - x0).hypot(y1 - y0);
        let m = (len * n as f64).round() as u32;
        let base = positions.len() as u32;
        for j in 0..=layers {
            for i in 0..=m {
                let s = i as f64 / m as f64;
                positions.push(Vec3::new(
                    x0 + s * (x1 - x0),
                    y0 + s * (y1 - y0),
                    depth * j as f64 / layers as f64,
                ));
            }
        }
        let at = |i: u32, j: u32| base + j * (m + 1) + i;
        for j in 0..layers {
            for i in 0..m {
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                triangles.push([a, b, c]);
                triangles.push([a, c, d]);
            }
        }
    }
    // The caps and sides share their rim vertices by position: the repair welds them.
    SurfaceMesh {
        positions,
        triangles,
    }
}

/// Pieces joined into one surface, each renumbered; `inward` turns a piece inside out.
pub fn joined(parts: &[(SurfaceMesh, bool)]) -> SurfaceMesh {
    let mut out = SurfaceMesh::default();
    for (part, inward) in parts {
        let base = out.positions.len() as u32;
        out.positions.extend(&part.positions);
        out.triangles.extend(part.triangles.iter().map(|t| {
            let t = t.map(|v| base + v);
            if *inward { [t[0], t[2], t[1]] } else { t }
        }));
    }
    out
}

/// A box of `size` with a corner at minus half of it, each face an `n`-per-unit grid of
/// squares split into triangles (outward): its volume is the closed form's exactly.
pub fn cuboid(size: Vec3, n: usize) -> SurfaceMesh {
    let half = size / 2.0;
    let mut out = SurfaceMesh::default();
    // Each face: the axis it faces along, its sign, and the two axes spanning it (ordered
    // so that u x v points out).
    for (axis, sign, u, v) in [
        (0, 1.0, 1, 2),
        (0, -1.0, 2, 1),
        (1, 1.0, 2, 0),
        (1, -1.0, 0, 2),
        (2, 1.0, 0, 1),
        (2, -1.0, 1, 0),
    ] {
        let (nu, nv) = (
            ((size[u] * n as f64).round() as usize).max(1),
            ((size[v] * n as f64).round() as usize).max(1),
        );
        let base = out.positions.len() as u32;
        for j in 0..=nv {
            for i in 0..=nu {
                let mut p = Vec3::zeros();
                p[axis] = sign * half[axis];
                p[u] = -half[u] + size[u] * i as f64 / nu as f64;
                p[v] = -half[v] + size[v] * j as f64 / nv as f64;
                out.positions.push(p);
            }
        }
        let at = |i: usize, j: usize| base + (j * (nu + 1) + i) as u32;
        for j in 0..nv {
            for i in 0..nu {
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                out.triangles.push([a, b, c]);
                out.triangles.push([a, c, d]);
            }
        }
    }
    // The faces share their rim vertices by position: the repair welds them.
    out
}

/// A capsule along z: a cylinder of `radius` and `length` (centred on the origin) between
/// two half balls, as one grid (48 around, 48 from pole to pole: 12 rings on each cap,
/// 24 along the cylinder).
pub fn capsule(radius: f64, length: f64) -> SurfaceMesh {
    grid(48, 48, false, |u, v| {
        let t = 2.0 * PI * u;
        // v in [0, 1/4]: the lower cap, [1/4, 3/4]: the cylinder, [3/4, 1]: the upper cap.
        let (rho, z) = if v < 0.25 {
            let a = PI / 2.0 * (1.0 - 4.0 * v);
            (radius * a.cos(), -length / 2.0 - radius * a.sin())
        } else if v <= 0.75 {
            (radius, -length / 2.0 + length * (v - 0.25) * 2.0)
        } else {
            let a = PI / 2.0 * (4.0 * v - 3.0);
            (radius * a.cos(), length / 2.0 + radius * a.sin())
        };
        Vec3::new(rho * t.cos(), rho * t.sin(), z)
    })
}

/// A closed cup: a cylinder of `radius` and `height` (base at z = 0) hollowed from the top,
/// its side wall and bottom `wall` thick, the rim closed; the profile revolved in `around`
/// steps, each of its segments cut about as long as one step along the outer circle.
pub fn cup(radius: f64, height: f64, wall: f64, around: usize) -> SurfaceMesh {
    let step = 2.0 * PI * radius / around as f64;
    let corners = [
        (0.0, 0.0),
        (radius, 0.0),
        (radius, height),
        (radius - wall, height),
        (radius - wall, wall),
        (0.0, wall),
    ];
    // The profile (rho, z), from the outer pole to the inner one.
    let mut profile = Vec::new();
    for w in corners.windows(2) {
        let ((r0, z0), (r1, z1)) = (w[0], w[1]);
        let n = ((r1 - r0).hypot(z1 - z0) / step).round().max(1.0) as usize;
        for k in 0..n {
            let s = k as f64 / n as f64;
            profile.push((r0 + s * (r1 - r0), z0 + s * (z1 - z0)));
        }
    }
    profile.push(corners[5]);
    let mut out = SurfaceMesh::default();
    let rings = profile.len() - 2;
    for &(rho, z) in &profile[1..=rings] {
        for i in 0..around {
            let a = 2.0 * PI * i as f64 / around as f64;
            out.positions
                .push(Vec3::new(rho * a.cos(), rho * a.sin(), z));
        }
    }
    let at = |ring: usize, i: usize| (ring * around + i % around) as u32;
    let (outer, inner) = (out.positions.len() as u32, out.positions.len() as u32 + 1);
    out.positions.push(Vec3::new(0.0, 0.0, 0.0));
    out.positions.push(Vec3::new(0.0, 0.0, wall));
    for i in 0..around {
        out.triangles.push([outer, at(0, i + 1), at(0, i)]);
        out.triangles
            .push([inner, at(rings - 1, i), at(rings - 1, i + 1)]);
        for r in 0..rings - 1 {
            let (a, b, c, d) = (at(r, i), at(r, i + 1), at(r + 1, i + 1), at(r + 1, i));
            out.triangles.push([a, b, c]);
            out.triangles.push([a, c, d]);
        }
    }
    out
}
