//! The contact surface of one body: its boundary triangles, the topology the inside test
//! needs (also where the surface is not a manifold), and a bounding-volume hierarchy kept
//! valid at little cost while the body moves.
//!
//! **Real meshes are not manifolds.** Tetrahedra that share only an edge or a vertex are
//! common in meshes from segmentation: their boundary then has edges with four (or six, ...)
//! triangles and vertices whose triangles form several cones. Inside and outside are still
//! well defined, by the tetrahedra. Each boundary triangle's partner across an edge is found by
//! walking around the edge through the tetrahedra behind the triangle (the fan of elements on
//! that edge) to the boundary face at the other end of the fan: the two faces bound the same
//! solid wedge, so the edge pseudo-normal made of their normals points out of that wedge. At a
//! vertex, the triangles linked through such pairs form one *sheet* (an umbrella); a vertex on
//! several sheets has one pseudo-normal per sheet, and a query uses the sheet of the triangle
//! it found. On a closed manifold this is exactly the angle-weighted pseudo-normal test of
//! Baerentzen and Aanaes (2005).
//!
//! **Pay for what is asked.** Face, edge and vertex normals are computed when a query lands on
//! that feature, not for the whole surface at every move. The hierarchy's leaf boxes are the
//! triangles' boxes grown by a slack (an eighth of the mean surface edge): a move only updates
//! the leaves of vertices that left their box (and the path above them), so a body that deforms
//! slowly keeps its tree for many steps.

use std::sync::atomic::{AtomicU64, Ordering};

use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, TraversalAction};

use super::{ContactError, to_parry_aabb};
use crate::Vec3;
use crate::geometry::closest_on_triangle;
use crate::mesh::{NO_NEIGHBOR, TetMesh};

/// Identities of colliders, so cached pair data can tell a body from another.
static NEXT_ID: AtomicU64 = AtomicU64::new(1);

/// The leaf boxes' slack as a fraction of the mean surface edge length.
const SLACK_FRACTION: f64 = 0.125;

/// When more leaves than this fraction changed, the tree is refitted whole (one pass) rather
/// than path by path.
const FULL_REFIT_FRACTION: usize = 8;

/// The closest surface point of a body to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceHit {
    /// Triangle (index into the collider's triangles).
    pub triangle: u32,
    /// Barycentric weights of the closest point in the triangle.
    pub weights: [f64; 3],
    /// The closest point.
    pub point: Vec3,
    /// Signed distance of the query point (negative inside the body).
    pub distance: f64,
    /// Unit outward direction at the contact (from the surface toward a point outside).
    pub normal: Vec3,
}

/// The boundary of one body for contact (see the module docs).
pub struct SurfaceCollider {
    id: u64,
    nodes: Vec<u32>,
    triangles: Vec<[u32; 3]>,
    /// Partner across edge `k` = (`t[k]`, `t[k + 1]`): the triangle bounding the same solid
    /// wedge on that edge.
    neighbors: Vec<[u32; 3]>,
    /// Sheet of each triangle corner.
    corner_sheet: Vec<[u32; 3]>,
    /// Corners `(triangle, corner)` of each sheet, in compressed rows.
    sheet_start: Vec<u32>,
    sheet_corners: Vec<(u32, u8)>,
    /// Triangles of each vertex, in compressed rows.
    vertex_start: Vec<u32>,
    vertex_triangles: Vec<u32>,
    non_manifold_edges: usize,
    non_manifold_vertices: usize,
    positions: Vec<Vec3>,
    /// Vertex positions the leaf boxes were last built around.
    anchors: Vec<Vec3>,
    slack: f64,
    bounds: (Vec3, Vec3),
    bvh: Bvh,
    /// Per-triangle mark of the current update, so a leaf is updated once.
    marks: Vec<u32>,
    mark: u32,
    changed: Vec<u32>,
    travel: f64,
    finite: bool,
}

impl std::fmt::Debug for SurfaceCollider {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SurfaceCollider")
            .field("vertices", &self.nodes.len())
            .field("triangles", &self.triangles.len())
            .field("non_manifold_edges", &self.non_manifold_edges)
            .field("non_manifold_vertices", &self.non_manifold_vertices)
            .field("bounds", &self.bounds)
            .finish()
    }
}

fn bounds_of(points: impl Iterator<Item = Vec3>) -> (Vec3, Vec3) {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    }
    (lo, hi)
}

/// Squared distance from `p` to a tree node's box (zero inside).
#[inline]
fn box_distance2(lo: parry3d::math::Vector, hi: parry3d::math::Vector, p: &Vec3) -> f64 {
    let mut d2 = 0.0;
    for (k, (l, h)) in [(lo.x, hi.x), (lo.y, hi.y), (lo.z, hi.z)]
        .into_iter()
        .enumerate()
    {
        let x = p[k];
        let d = (l as f64 - x).max(x - h as f64).max(0.0);
        d2 += d * d;
    }
    d2
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[parent[x as usize] as usize];
        parent[x as usize] = p;
        x = p;
    }
    x
}

fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        parent[ra.max(rb) as usize] = ra.min(rb);
    }
}

/// Compressed rows of `items` grouped by their key (keys below `rows`), each row in item
/// order: the row starts (`rows + 1` entries) and the items.
fn rows<T: Copy + Default>(rows: usize, items: &[(usize, T)]) -> (Vec<u32>, Vec<T>) {
    let mut start = vec![0u32; rows + 1];
    for &(k, _) in items {
        start[k + 1] += 1;
    }
    for i in 0..rows {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut out = vec![T::default(); items.len()];
    for &(k, item) in items {
        out[fill[k] as usize] = item;
        fill[k] += 1;
    }
    (start, out)
}

impl SurfaceCollider {
    /// Builds the collider of `mesh`'s boundary at its rest positions. Any mesh that passed
    /// [`TetMesh`] validation has a usable boundary: non-manifold edges and vertices, several
    /// pieces and unused nodes are all taken (see the module docs).
    pub fn new(mesh: &TetMesh) -> Result<Self, ContactError> {
        let surface = mesh.surface();
        let nodes = surface.vertices().to_vec();
        let triangles = surface.local_triangles().to_vec();
        let global = surface.triangles();
        let owners = surface.triangle_tets();
        let tets = mesh.tets();
        let across = mesh.tet_neighbors();
        let nt = triangles.len();
        if nt == 0 {
            return Err(ContactError::BadSurface {
                triangle: 0,
                reason: "the mesh has no boundary triangles".into(),
            });
        }
        // Partner of each (triangle, edge): walk around the edge through the fan of
        // tetrahedra behind the triangle to the boundary face at its other end.
        let mut neighbors = vec![[u32::MAX; 3]; nt];
        for (t, tri) in global.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let (mut tet, _) = owners[t];
                // The entry face's vertex off the edge; the exit face is opposite it.
                let mut w = tri[(k + 2) % 3];
                let limit = mesh.node_tets(a as usize).len() + 2;
                let mut partner = None;
                for _ in 0..limit {
                    let corners = tets[tet as usize];
                    let Some(iw) = corners.iter().position(|&c| c == w) else {
                        break;
                    };
                    let next = across[tet as usize][iw];
                    if next == NO_NEIGHBOR {
                        partner = owners.binary_search(&(tet, iw as u8)).ok();
                        break;
                    }
                    let Some(&u) = corners.iter().find(|&&c| c != a && c != b && c != w) else {
                        break;
                    };
                    tet = next;
                    w = u;
                }
                match partner {
                    Some(p) if p != t => neighbors[t][k] = p as u32,
                    _ => {
                        return Err(ContactError::BadSurface {
                            triangle: t,
                            reason: format!(
                                "no boundary face closes the elements around edge ({a}, {b})"
                            ),
                        });
                    }
                }
            }
        }
        // Edges on more than two triangles.
        let mut edge_keys: Vec<(u32, u32)> = global
            .iter()
            .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
            .collect();
        edge_keys.sort_unstable();
        let non_manifold_edges = edge_keys
            .chunk_by(|x, y| x == y)
            .filter(|g| g.len() > 2)
            .count();
        // Sheets: the corners at a vertex linked through partners across the two edges of
        // the corner.
        let mut parent: Vec<u32> = (0..3 * nt as u32).collect();
        for t in 0..nt {
            for k in 0..3 {
                let v = triangles[t][k];
                for edge in [k, (k + 2) % 3] {
                    let t2 = neighbors[t][edge] as usize;
                    if let Some(k2) = triangles[t2].iter().position(|&x| x == v) {
                        union(&mut parent, (3 * t + k) as u32, (3 * t2 + k2) as u32);
                    }
                }
            }
        }
        let mut sheet_of_root = vec![u32::MAX; 3 * nt];
        let mut corner_sheet = vec![[0u32; 3]; nt];
        let mut sheets = 0u32;
        let mut sheet_vertex = Vec::new();
        for c in 0..3 * nt {
            let r = find(&mut parent, c as u32) as usize;
            if sheet_of_root[r] == u32::MAX {
                sheet_of_root[r] = sheets;
                sheet_vertex.push(triangles[c / 3][c % 3]);
                sheets += 1;
            }
            corner_sheet[c / 3][c % 3] = sheet_of_root[r];
        }
        let corners: Vec<(usize, (u32, u8))> = (0..3 * nt)
            .map(|c| {
                let (t, k) = (c / 3, c % 3);
                (corner_sheet[t][k] as usize, (t as u32, k as u8))
            })
            .collect();
        let (sheet_start, sheet_corners) = rows(sheets as usize, &corners);
        let mut sheets_per_vertex = vec![0u32; nodes.len()];
        for &v in &sheet_vertex {
            sheets_per_vertex[v as usize] += 1;
        }
        let non_manifold_vertices = sheets_per_vertex.iter().filter(|&&s| s > 1).count();
        let incidences: Vec<(usize, u32)> = (0..3 * nt)
            .map(|c| (triangles[c / 3][c % 3] as usize, (c / 3) as u32))
            .collect();
        let (vertex_start, vertex_triangles) = rows(nodes.len(), &incidences);
        let positions: Vec<Vec3> = nodes
            .iter()
            .map(|&i| mesh.positions()[i as usize])
            .collect();
        let edge_sum: f64 = triangles
            .iter()
            .flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3])))
            .map(|(a, b)| (positions[a as usize] - positions[b as usize]).norm())
            .sum();
        let mean_edge = edge_sum / (3 * nt) as f64;
        let slack = if mean_edge.is_finite() && mean_edge > 0.0 {
            SLACK_FRACTION * mean_edge
        } else {
            0.0
        };
        let mut collider = SurfaceCollider {
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            bounds: bounds_of(positions.iter().copied()),
            anchors: positions.clone(),
            nodes,
            neighbors,
            corner_sheet,
            sheet_start,
            sheet_corners,
            vertex_start,
            vertex_triangles,
            non_manifold_edges,
            non_manifold_vertices,
            positions,
            slack,
            bvh: Bvh::new(),
            marks: vec![0; nt],
            mark: 0,
            changed: Vec::with_capacity(nt),
            travel: 0.0,
            finite: true,
            triangles,
        };
        let leaves: Vec<ParryAabb> = (0..nt).map(|t| collider.leaf_box(t)).collect();
        collider.bvh = Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves);
        Ok(collider)
    }

    /// A number no other collider of this process has (cached pair data checks it).
    pub fn id(&self) -> u64 {
        self.id
    }

    /// Mesh node of each surface vertex.
    pub fn nodes(&self) -> &[u32] {
        &self.nodes
    }

    /// Triangles, as indices into [`SurfaceCollider::nodes`].
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Surface positions as last gathered.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// Bounds of the surface as last gathered.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// Boundary edges shared by more than two triangles (tetrahedra meeting along an edge
    /// only).
    pub fn non_manifold_edges(&self) -> usize {
        self.non_manifold_edges
    }

    /// Surface vertices on more than one sheet (tetrahedra meeting at a vertex only, or
    /// around a non-manifold edge).
    pub fn non_manifold_vertices(&self) -> usize {
        self.non_manifold_vertices
    }

    /// Partner triangle across edge `k` (`t[k]`, `t[k + 1]`) of triangle `t`: the one
    /// bounding the same solid wedge.
    pub fn neighbor(&self, t: usize, k: usize) -> u32 {
        self.neighbors[t][k]
    }

    /// A bound on how far any surface vertex has moved since the collider was built: the sum
    /// over gathers of the largest move of a vertex. Two bodies whose travels grew by `d1`
    /// and `d2` since some moment have no two points that came closer than they were then by
    /// more than `d1 + d2`. Infinite once a position was not finite.
    pub fn travel(&self) -> f64 {
        self.travel
    }

    /// Forgets the travel and a past non-finite position, and rebuilds the leaf boxes around
    /// `node_positions` (a body put back to its initial state).
    pub fn reset_motion(&mut self, node_positions: &[Vec3]) {
        self.finite = true;
        self.travel = 0.0;
        for (v, &i) in self.nodes.iter().enumerate() {
            self.positions[v] = node_positions[i as usize];
        }
        self.anchors.copy_from_slice(&self.positions);
        self.bounds = bounds_of(self.positions.iter().copied());
        for t in 0..self.triangles.len() {
            let leaf = self.leaf_box(t);
            let _ = self.bvh.update_partially_if_present(leaf, t as u32, 0.0);
        }
        self.bvh.refit_without_opt();
    }

    /// Whether every gathered position was finite.
    pub fn is_finite(&self) -> bool {
        self.finite
    }

    fn leaf_box(&self, t: usize) -> ParryAabb {
        let b = bounds_of(self.triangles[t].iter().map(|&i| self.anchors[i as usize]));
        let s = Vec3::repeat(self.slack);
        to_parry_aabb(&(b.0 - s), &(b.1 + s))
    }

    /// Copies the surface positions from the body's node positions, updates the bounds, the
    /// travel and the leaves of vertices that left their boxes. Queries are valid afterwards.
    pub fn gather(&mut self, node_positions: &[Vec3]) {
        let mut lo = Vec3::repeat(f64::INFINITY);
        let mut hi = Vec3::repeat(f64::NEG_INFINITY);
        let mut largest: f64 = 0.0;
        let mut finite = true;
        self.mark = self.mark.wrapping_add(1);
        if self.mark == 0 {
            self.marks.fill(0);
            self.mark = 1;
        }
        self.changed.clear();
        for v in 0..self.nodes.len() {
            let p = node_positions[self.nodes[v] as usize];
            if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
                finite = false;
                self.positions[v] = p;
                continue;
            }
            let d2 = (p - self.positions[v]).norm_squared();
            if d2 > largest {
                largest = d2;
            }
            self.positions[v] = p;
            lo = lo.inf(&p);
            hi = hi.sup(&p);
            let a = self.anchors[v];
            if (p - a).amax() > self.slack {
                self.anchors[v] = p;
                let (s, e) = (
                    self.vertex_start[v] as usize,
                    self.vertex_start[v + 1] as usize,
                );
                for &t in &self.vertex_triangles[s..e] {
                    if self.marks[t as usize] != self.mark {
                        self.marks[t as usize] = self.mark;
                        self.changed.push(t);
                    }
                }
            }
        }
        self.bounds = (lo, hi);
        self.finite &= finite;
        self.travel = if self.finite {
            self.travel + largest.sqrt()
        } else {
            f64::INFINITY
        };
        if self.changed.is_empty() {
            return;
        }
        for i in 0..self.changed.len() {
            let t = self.changed[i];
            let leaf = self.leaf_box(t as usize);
            let _ = self.bvh.update_partially_if_present(leaf, t, 0.0);
        }
        if self.changed.len() * FULL_REFIT_FRACTION > self.triangles.len() {
            self.bvh.refit_without_opt();
        } else {
            self.bvh.refit_partial(&[], &self.changed);
        }
    }

    /// Unit normal of triangle `t` at the gathered positions (zero when it has no area).
    pub fn face_normal(&self, t: usize) -> Vec3 {
        let [a, b, c] = self.triangles[t].map(|i| self.positions[i as usize]);
        let n = (b - a).cross(&(c - a));
        let len = n.norm();
        if len > 0.0 { n / len } else { Vec3::zeros() }
    }

    /// Unit angle-weighted normal of vertex `v` over all its triangles (every sheet of a
    /// non-manifold vertex together; zero when they cancel or `v` has none).
    pub fn vertex_normal(&self, v: usize) -> Vec3 {
        let Some(range) = self
            .vertex_start
            .get(v)
            .zip(self.vertex_start.get(v + 1))
            .map(|(&a, &b)| a as usize..b as usize)
        else {
            return Vec3::zeros();
        };
        let mut n = Vec3::zeros();
        for &t in &self.vertex_triangles[range] {
            let tri = self.triangles[t as usize];
            let Some(k) = tri.iter().position(|&x| x as usize == v) else {
                continue;
            };
            let p = self.positions[v];
            let e1 = self.positions[tri[(k + 1) % 3] as usize] - p;
            let e2 = self.positions[tri[(k + 2) % 3] as usize] - p;
            let angle = e1.cross(&e2).norm().atan2(e1.dot(&e2));
            n += self.face_normal(t as usize) * angle;
        }
        n.try_normalize(0.0).unwrap_or_else(Vec3::zeros)
    }

    /// Angle-weighted normal of the sheet of corner `k` of triangle `t`.
    fn sheet_normal(&self, t: usize, k: usize) -> Vec3 {
        let s = self.corner_sheet[t][k] as usize;
        let (from, to) = (
            self.sheet_start[s] as usize,
            self.sheet_start[s + 1] as usize,
        );
        let mut n = Vec3::zeros();
        for &(tt, kk) in &self.sheet_corners[from..to] {
            let tri = self.triangles[tt as usize];
            let kk = kk as usize;
            let p = self.positions[tri[kk] as usize];
            let e1 = self.positions[tri[(kk + 1) % 3] as usize] - p;
            let e2 = self.positions[tri[(kk + 2) % 3] as usize] - p;
            let angle = e1.cross(&e2).norm().atan2(e1.dot(&e2));
            n += self.face_normal(tt as usize) * angle;
        }
        n
    }

    /// Outward pseudo-normal at the feature of triangle `t` the weights `w` name (face, edge
    /// or vertex).
    fn pseudo_normal(&self, t: usize, w: &[f64; 3]) -> Vec3 {
        let zeros = w.iter().filter(|&&x| x == 0.0).count();
        match zeros {
            0 => self.face_normal(t),
            1 => {
                // On the edge opposite the zero weight: edge k = (t[k], t[k+1]) with the zero
                // at k + 2.
                let z = w.iter().position(|&x| x == 0.0).unwrap_or(0);
                let k = (z + 1) % 3;
                self.face_normal(t) + self.face_normal(self.neighbors[t][k] as usize)
            }
            _ => {
                let k = w.iter().position(|&x| x != 0.0).unwrap_or(0);
                self.sheet_normal(t, k)
            }
        }
    }

    /// Closest surface point to `p` within `radius`, with its signed distance (negative
    /// inside) from the pseudo-normal of the closest feature. `None` when no triangle is that
    /// close. Valid after [`SurfaceCollider::gather`].
    pub fn closest(&self, p: &Vec3, radius: f64) -> Option<SurfaceHit> {
        if radius.is_nan() || radius < 0.0 {
            return None;
        }
        let mut best_d2 = radius * radius;
        let mut best: Option<(u32, [f64; 3], Vec3)> = None;
        self.bvh.traverse(|node| {
            if box_distance2(node.mins(), node.maxs(), p) > best_d2 {
                return TraversalAction::Prune;
            }
            if let Some(t) = node.leaf_data() {
                let [a, b, c] = self.triangles[t as usize].map(|i| self.positions[i as usize]);
                let w = closest_on_triangle(p, &a, &b, &c);
                let q = a * w[0] + b * w[1] + c * w[2];
                let e2 = (p - q).norm_squared();
                let better = match best {
                    None => e2 <= best_d2,
                    Some((bt, _, _)) => e2 < best_d2 || (e2 == best_d2 && t < bt),
                };
                if better {
                    best_d2 = e2;
                    best = Some((t, w, q));
                }
            }
            TraversalAction::Continue
        });
        let (t, w, q) = best?;
        let d = best_d2.sqrt();
        let pseudo = self.pseudo_normal(t as usize, &w);
        let offset = p - q;
        let sign = if offset.dot(&pseudo) < 0.0 { -1.0 } else { 1.0 };
        let normal = if d > 1e-12 * (1.0 + q.norm()) {
            offset * (sign / d)
        } else {
            pseudo
                .try_normalize(0.0)
                .unwrap_or_else(|| self.face_normal(t as usize))
        };
        Some(SurfaceHit {
            triangle: t,
            weights: w,
            point: q,
            distance: sign * d,
            normal,
        })
    }

    /// Whether some triangle is within `radius` of `p` (stops at the first one found).
    pub fn within(&self, p: &Vec3, radius: f64) -> bool {
        if radius.is_nan() || radius < 0.0 {
            return false;
        }
        let r2 = radius * radius;
        let mut found = false;
        self.bvh.traverse(|node| {
            if box_distance2(node.mins(), node.maxs(), p) > r2 {
                return TraversalAction::Prune;
            }
            if let Some(t) = node.leaf_data() {
                let [a, b, c] = self.triangles[t as usize].map(|i| self.positions[i as usize]);
                let w = closest_on_triangle(p, &a, &b, &c);
                let q = a * w[0] + b * w[1] + c * w[2];
                if (p - q).norm_squared() <= r2 {
                    found = true;
                    return TraversalAction::EarlyExit;
                }
            }
            TraversalAction::Continue
        });
        found
    }

    /// Triangles whose boxes meet `[lo, hi]`, in ascending order, into `out` (cleared first).
    pub fn triangles_in(&self, lo: &Vec3, hi: &Vec3, out: &mut Vec<u32>) {
        out.clear();
        let query = to_parry_aabb(lo, hi);
        out.extend(self.bvh.intersect_aabb(&query));
        out.sort_unstable();
    }
}
