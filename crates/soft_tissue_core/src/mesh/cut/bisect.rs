//! Moves 1 and 2 of a cut (bisection and snapping) and the choice of the faces to
//! separate (see the module docs of [`super`]).

use std::collections::HashMap;

use super::*;

impl Work<'_> {
    /// Whether the incision cutting now passed through node `v` before.
    pub(super) fn on_incision(&self, v: u32) -> bool {
        self.incision != 0 && self.marked[v as usize] == self.incision
    }

    /// Bisects the edges crossing `tri` inside it (moves 1 and 2 of the module docs);
    /// returns the nodes' distances to its plane and which count as on it, for
    /// [`Work::separate_by`], or `None` when the triangle meets no tetrahedron.
    pub(super) fn bisect_by(
        &mut self,
        tri: &CutTriangle,
        snap: f64,
        limit: Option<(Vec3, Vec3)>,
    ) -> Option<PlaneNodes> {
        let [a, b, c] = tri.corners;
        let normal = (b - a).cross(&(c - a)).normalize();
        let offset = normal.dot(&a);
        let (mut lo, mut hi) = (a.inf(&b).inf(&c), a.sup(&b).sup(&c));
        if let Some((l, h)) = limit {
            (lo, hi) = (lo.sup(&l), hi.inf(&h));
            if (0..3).any(|k| lo[k] > hi[k]) {
                return None;
            }
        }
        // Candidates: tetrahedra whose box meets the triangle's, grown by what snapping
        // reaches (`snap` of the longest edge there), so both tetrahedra of a face moved onto
        // the plane are among them.
        let boxes = |pad: f64| {
            (0..self.tets.len() as u32)
                .filter(|&t| {
                    let p = self.tets[t as usize].map(|i| self.positions[i as usize]);
                    let tl = p[0].inf(&p[1]).inf(&p[2]).inf(&p[3]);
                    let th = p[0].sup(&p[1]).sup(&p[2]).sup(&p[3]);
                    (0..3).all(|k| tl[k] <= hi[k] + pad && th[k] >= lo[k] - pad)
                })
                .collect::<Vec<u32>>()
        };
        let touching = boxes(1e-9 * (hi - lo).norm());
        let longest = touching
            .iter()
            .flat_map(|&t| {
                let tet = self.tets[t as usize];
                [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)].map(|(i, j)| {
                    (self.positions[tet[i] as usize] - self.positions[tet[j] as usize]).norm()
                })
            })
            .fold(0.0, f64::max);
        let reach = snap * longest;
        let mut candidates = boxes(1e-9 * (hi - lo).norm() + reach);
        if candidates.is_empty() {
            return None;
        }
        // Signed distances, and which nodes count as on the plane.
        let mut distance: HashMap<u32, f64> = HashMap::new();
        for &t in &candidates {
            for &v in &self.tets[t as usize] {
                distance
                    .entry(v)
                    .or_insert_with(|| normal.dot(&self.positions[v as usize]) - offset);
            }
        }
        // A node closer to the plane than `snap` of its shortest edge there is on it (and
        // within the candidates' reach, so both tetrahedra of a face on the plane are
        // candidates).
        let mut shortest: HashMap<u32, f64> = HashMap::new();
        for &t in &candidates {
            let tet = self.tets[t as usize];
            for i in 0..4 {
                for j in i + 1..4 {
                    let l =
                        (self.positions[tet[i] as usize] - self.positions[tet[j] as usize]).norm();
                    for v in [tet[i], tet[j]] {
                        let e = shortest.entry(v).or_insert(f64::INFINITY);
                        *e = e.min(l);
                    }
                }
            }
        }
        // Nodes on the sides of earlier cuts within snapping reach stay on the plane: a
        // blade that cuts again where it cut before (an incision re-cut as it grows) keeps
        // the surface it made there, though new short edges around a node would no longer
        // snap it (which would leave a sliver of elements between two cut surfaces).
        let mut on_side: Vec<u32> = Vec::new();
        for &t in &candidates {
            let tet = self.tets[t as usize];
            for (o, &f) in self.cut[t as usize].iter().enumerate() {
                if f {
                    on_side.extend(face_key(&tet, o));
                }
            }
        }
        on_side.sort_unstable();
        on_side.dedup();
        let mut on_plane: HashMap<u32, bool> = distance
            .iter()
            .map(|(&v, &d)| {
                let snapped = d.abs() < snap * shortest[&v] || on_side.binary_search(&v).is_ok();
                // A node this incision passed is on its plane wherever it moved since, within
                // an element (not the marks of another strip of a curved path).
                let passed = self.on_incision(v) && d.abs() <= longest;
                let on = d == 0.0 || passed || (snapped && d.abs() <= reach);
                (v, on)
            })
            .collect();
        // Crossing edges with their crossing inside the triangle; a crossing near an end puts
        // that end on the plane instead (repeat until no new end joins the plane).
        let crossing = |edge: (u32, u32),
                        distance: &HashMap<u32, f64>,
                        on_plane: &HashMap<u32, bool>|
         -> Option<f64> {
            let (da, db) = (distance[&edge.0], distance[&edge.1]);
            if on_plane[&edge.0] || on_plane[&edge.1] || (da > 0.0) == (db > 0.0) {
                return None;
            }
            Some(da / (da - db))
        };
        let mut edges: Vec<(u32, u32)> = Vec::new();
        for &t in &candidates {
            let tet = self.tets[t as usize];
            for i in 0..4 {
                for j in i + 1..4 {
                    let (u, v) = (tet[i].min(tet[j]), tet[i].max(tet[j]));
                    edges.push((u, v));
                }
            }
        }
        edges.sort_unstable();
        edges.dedup();
        let point = |w: &Work, e: (u32, u32), s: f64| {
            w.positions[e.0 as usize] * (1.0 - s) + w.positions[e.1 as usize] * s
        };
        loop {
            let mut changed = false;
            for &e in &edges {
                let Some(s) = crossing(e, &distance, &on_plane) else {
                    continue;
                };
                if !inside(tri, &point(self, e, s)) {
                    continue;
                }
                if s < snap {
                    on_plane.insert(e.0, true);
                    changed = true;
                } else if s > 1.0 - snap {
                    on_plane.insert(e.1, true);
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        // Bisect the crossing edges whose crossing lies inside the triangle.
        for &e in &edges {
            let Some(s) = crossing(e, &distance, &on_plane) else {
                continue;
            };
            let p = point(self, e, s);
            if !inside(tri, &p) {
                continue;
            }
            let node = self.split_edge(e, s, &mut candidates);
            distance.insert(node, 0.0);
            on_plane.insert(node, true);
        }
        if self.incision != 0 {
            for (&v, &on) in &on_plane {
                if on {
                    self.marked[v as usize] = self.incision;
                }
            }
        }
        Some(PlaneNodes {
            distance,
            on_plane,
            reach,
        })
    }

    /// Chooses the faces on `tri`'s plane inside it between tetrahedra on opposite sides
    /// (move 3) into `chosen`, with their two tetrahedra, once every triangle of the blade
    /// has bisected: a face made by a neighbouring triangle's bisections but lying in this
    /// one is found here. Nodes made
    /// since [`Work::bisect_by`] classified them count as on the plane within 1e-9 of the
    /// triangle's size (a coplanar neighbour's).
    pub(super) fn separate_by(
        &mut self,
        tri: &CutTriangle,
        nodes: PlaneNodes,
        region: &[CutTriangle],
        chosen: &mut HashMap<[u32; 3], Vec<(u32, u8)>>,
    ) {
        let PlaneNodes {
            mut distance,
            mut on_plane,
            reach,
        } = nodes;
        let [a, b, c] = tri.corners;
        let normal = (b - a).cross(&(c - a)).normalize();
        let offset = normal.dot(&a);
        let scale = (b - a).norm().max((c - a).norm());
        // Where faces may be separated: the triangle, and the region's triangles in its
        // plane (the part of an incision already swept, whose faces wider than one step
        // are completed by this step's bisections).
        let mut areas: Vec<&CutTriangle> = vec![tri];
        areas.extend(region.iter().filter(|r| {
            r.corners
                .iter()
                .all(|p| (normal.dot(p) - offset).abs() <= 1e-6 * scale)
        }));
        let (lo, hi) = areas.iter().fold((a, a), |(lo, hi), t| {
            let [p, q, r] = t.corners;
            (lo.inf(&p).inf(&q).inf(&r), hi.sup(&p).sup(&q).sup(&r))
        });
        let pad = 1e-9 * (hi - lo).norm() + reach;
        let candidates: Vec<u32> = (0..self.tets.len() as u32)
            .filter(|&t| {
                let p = self.tets[t as usize].map(|i| self.positions[i as usize]);
                let tl = p[0].inf(&p[1]).inf(&p[2]).inf(&p[3]);
                let th = p[0].sup(&p[1]).sup(&p[2]).sup(&p[3]);
                (0..3).all(|k| tl[k] <= hi[k] + pad && th[k] >= lo[k] - pad)
            })
            .collect();
        let size = (hi - lo).norm();
        for &t in &candidates {
            for &v in &self.tets[t as usize] {
                if let std::collections::hash_map::Entry::Vacant(e) = distance.entry(v) {
                    let d = normal.dot(&self.positions[v as usize]) - offset;
                    e.insert(d);
                    on_plane.insert(v, d.abs() <= 1e-9 * size || self.on_incision(v));
                }
            }
        }
        // Faces on the plane, inside the triangle, between tetrahedra on opposite sides.
        let mut faces: HashMap<[u32; 3], Vec<(u32, u8)>> = HashMap::new();
        for &t in &candidates {
            let tet = self.tets[t as usize];
            for opposite in 0..4 {
                let key = face_key(&tet, opposite);
                if key
                    .iter()
                    .all(|v| on_plane.get(v).copied().unwrap_or(false))
                {
                    faces.entry(key).or_default().push((t, opposite as u8));
                }
            }
        }
        // A tetrahedron's side: that of its corners off the plane (one side once the
        // crossing edges are bisected). One with all four corners counted on the plane,
        // lying flat against it, goes to the side most of its neighbours through faces are
        // on (so it stays joined to them, not cut loose as a crumb of one element), else to
        // the side its centre leans to; the same for all its faces.
        let d = |v: &u32| distance.get(v).copied().unwrap_or(0.0);
        let sign = |x: f64| if x < 0.0 { -1.0 } else { 1.0 };
        let mut sides: HashMap<u32, f64> = HashMap::new();
        let mut flat: Vec<u32> = Vec::new();
        for &t in &candidates {
            let tet = &self.tets[t as usize];
            let off: f64 = tet.iter().filter(|v| !on_plane[*v]).map(d).sum();
            if off != 0.0 {
                sides.insert(t, sign(off));
            } else {
                flat.push(t);
            }
        }
        let mut flat_sides = Vec::with_capacity(flat.len());
        for &t in &flat {
            let tet = self.tets[t as usize];
            let mut vote = 0.0;
            for opposite in 0..4 {
                if let Some(h) = faces.get(&face_key(&tet, opposite)) {
                    vote += h
                        .iter()
                        .filter(|(u, _)| *u != t)
                        .filter_map(|(u, _)| sides.get(u))
                        .sum::<f64>();
                }
            }
            let lean = if vote != 0.0 {
                vote
            } else {
                tet.iter().map(d).sum()
            };
            flat_sides.push((t, sign(lean)));
        }
        sides.extend(flat_sides);
        let side = |_: &Work, t: u32| sides.get(&t).copied().unwrap_or(1.0);
        let mut separate: Vec<[u32; 3]> = faces
            .iter()
            .filter(|(key, holders)| {
                if holders.len() != 2 {
                    return false;
                }
                let (s0, s1) = (side(self, holders[0].0), side(self, holders[1].0));
                if s0 == s1 {
                    return false;
                }
                let centre = key
                    .iter()
                    .fold(Vec3::zeros(), |s, &v| s + self.positions[v as usize])
                    / 3.0;
                let p = centre - normal * (normal.dot(&centre) - offset);
                areas.iter().any(|t| inside(t, &p))
            })
            .map(|(key, _)| *key)
            .collect();
        separate.sort_unstable();
        for f in &separate {
            chosen.entry(*f).or_insert_with(|| faces[f].clone());
        }
    }

    /// Bisects edge `e` at `(1 - s) e.0 + s e.1`: a new node there (marked by the incision
    /// cutting now), and every tetrahedron among `candidates` holding the edge split in two
    /// by it, the second child appended to the mesh and to `candidates`. Each child keeps
    /// its parent's orientation and cut sides on the parts of its faces. Returns the node.
    pub(super) fn split_edge(&mut self, e: (u32, u32), s: f64, candidates: &mut Vec<u32>) -> u32 {
        let p = self.positions[e.0 as usize] * (1.0 - s) + self.positions[e.1 as usize] * s;
        let node = self.positions.len() as u32;
        self.positions.push(p);
        self.marked.push(self.incision);
        let origin = self.origin_on_edge(e.0, e.1, s);
        self.node_origin.push(origin);
        self.bisected += 1;
        let holders: Vec<u32> = candidates
            .iter()
            .copied()
            .filter(|&t| {
                let tet = &self.tets[t as usize];
                tet.contains(&e.0) && tet.contains(&e.1)
            })
            .collect();
        for t in holders {
            let tet = self.tets[t as usize];
            let i = tet.iter().position(|&v| v == e.0).expect("holds the edge");
            let j = tet.iter().position(|&v| v == e.1).expect("holds the edge");
            let mut first = tet;
            first[j] = node;
            let mut second = tet;
            second[i] = node;
            // The face between the children is new and inside; the others are parts of the
            // parent's.
            let flags = self.cut[t as usize];
            let (mut f1, mut f2) = (flags, flags);
            f1[i] = false;
            f2[j] = false;
            self.tets[t as usize] = first;
            self.cut[t as usize] = f1;
            self.tets.push(second);
            self.cut.push(f2);
            self.tet_origin.push(self.tet_origin[t as usize]);
            candidates.push(self.tets.len() as u32 - 1);
        }
        node
    }
}
