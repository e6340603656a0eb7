//! Move 3 of a cut: separating the chosen faces by duplicating their nodes, keeping the
//! boundary 2-manifold and cutting no crumbs (see the module docs of [`super`]).

use std::collections::HashMap;

use super::*;

impl Work<'_> {
    /// Separates `faces` (with their two tetrahedra in `holders`), taking back faces until
    /// every edge of the boundary near them is in exactly two boundary triangles.
    pub(super) fn separate(
        &mut self,
        faces: &[[u32; 3]],
        holders: &HashMap<[u32; 3], Vec<(u32, u8)>>,
        centre: Vec3,
    ) {
        let mut chosen: Vec<[u32; 3]> = faces.to_vec();
        loop {
            if chosen.is_empty() {
                return;
            }
            let plan = self.plan_split(&chosen);
            // A face whose two sides keep the same copies of all three corners (a patch the
            // front closes all around) would not open: it is no cut.
            let group_of = |t: u32, v: u32| match plan.binary_search_by_key(&v, |(n, _)| *n) {
                Ok(k) => plan[k].1.iter().position(|g| g.contains(&t)),
                Err(_) => None,
            };
            let before = chosen.len();
            chosen.retain(|f| {
                let h = &holders[f];
                f.iter()
                    .any(|&v| group_of(h[0].0, v) != group_of(h[1].0, v))
            });
            if chosen.len() < before {
                self.taken_back += before - chosen.len();
                continue;
            }
            let bad = self.non_manifold_edges(&plan, &chosen, holders);
            // A piece of a few elements cut loose between the blade and a nearby surface
            // (a crumb, below what the mesh resolves) is not cut off: its faces are taken
            // back.
            let crumbs = if bad.is_empty() {
                self.crumbs(&plan, &chosen, holders)
            } else {
                Vec::new()
            };
            if !crumbs.is_empty() {
                let before = chosen.len();
                chosen.retain(|f| {
                    !holders[f]
                        .iter()
                        .any(|(t, _)| crumbs.binary_search(t).is_ok())
                });
                self.taken_back += before - chosen.len();
                continue;
            }
            if bad.is_empty() {
                self.apply_split(plan);
                self.separated += chosen.len();
                for f in &chosen {
                    for &(t, o) in &holders[f] {
                        self.cut[t as usize][o as usize] = true;
                    }
                }
                return;
            }
            // Take back one separated face at each bad edge (the one farther from the blade's
            // centre: the front's side), then plan again.
            let before = chosen.len();
            let mut drop: Vec<usize> = Vec::new();
            for &(u, v) in &bad {
                let far = chosen
                    .iter()
                    .enumerate()
                    .filter(|(k, f)| f.contains(&u) && f.contains(&v) && !drop.contains(k))
                    .max_by(|(_, f), (_, g)| {
                        let d = |f: &[u32; 3]| {
                            let c = f
                                .iter()
                                .fold(Vec3::zeros(), |s, &i| s + self.positions[i as usize])
                                / 3.0;
                            (c - centre).norm_squared()
                        };
                        d(f).total_cmp(&d(g)).then(f.cmp(g))
                    })
                    .map(|(k, _)| k);
                if let Some(k) = far {
                    drop.push(k);
                }
            }
            drop.sort_unstable();
            for k in drop.into_iter().rev() {
                chosen.remove(k);
            }
            self.taken_back += before - chosen.len();
            if chosen.len() == before {
                // No chosen face holds a bad edge (the mesh's own defect there): cut nothing
                // rather than leave a boundary that is not 2-manifold.
                self.taken_back += chosen.len();
                return;
            }
        }
    }

    /// The tetrahedra (sorted) of the crumbs `plan` would cut loose: new pieces (holding a
    /// tetrahedron of a separated face) under 2 % of the mesh's tetrahedra that have fewer
    /// than [`CRUMB_TETS`] or are one layer thick along the cut (every tetrahedron touches
    /// a separated face).
    pub(super) fn crumbs(
        &self,
        plan: &[(u32, Vec<Vec<u32>>)],
        separated: &[[u32; 3]],
        holders: &HashMap<[u32; 3], Vec<(u32, u8)>>,
    ) -> Vec<u32> {
        let n = self.positions.len();
        // Node copies after the split: the node itself, or one per extra group.
        let mut extra = vec![0usize; plan.len()];
        let mut count = n;
        for (k, (_, groups)) in plan.iter().enumerate() {
            extra[k] = count;
            count += groups.len().saturating_sub(1);
        }
        let copy = |t: u32, v: u32| -> usize {
            match plan.binary_search_by_key(&v, |(m, _)| *m) {
                Ok(k) => match plan[k].1.iter().position(|g| g.contains(&t)) {
                    Some(0) | None => v as usize,
                    Some(g) => extra[k] + g - 1,
                },
                Err(_) => v as usize,
            }
        };
        let tets = self.tets.len();
        let mut parent: Vec<u32> = (0..tets as u32).collect();
        fn root(p: &mut [u32], mut x: u32) -> u32 {
            while p[x as usize] != x {
                p[x as usize] = p[p[x as usize] as usize];
                x = p[x as usize];
            }
            x
        }
        let mut first = vec![u32::MAX; count];
        for (t, tet) in self.tets.iter().enumerate() {
            for &v in tet {
                let c = copy(t as u32, v);
                if first[c] == u32::MAX {
                    first[c] = t as u32;
                } else {
                    let (a, b) = (root(&mut parent, first[c]), root(&mut parent, t as u32));
                    if a != b {
                        parent[a.max(b) as usize] = a.min(b);
                    }
                }
            }
        }
        // A piece is deep when one of its tetrahedra does not touch the cut.
        let mut on_cut: Vec<u32> = separated.iter().flatten().copied().collect();
        on_cut.sort_unstable();
        on_cut.dedup();
        let mut size = vec![0usize; tets];
        let mut deep = vec![false; tets];
        for t in 0..tets as u32 {
            let r = root(&mut parent, t) as usize;
            size[r] += 1;
            if !self.tets[t as usize]
                .iter()
                .any(|v| on_cut.binary_search(v).is_ok())
            {
                deep[r] = true;
            }
        }
        let mut small: Vec<u32> = separated
            .iter()
            .flat_map(|f| holders[f].iter().map(|(t, _)| *t))
            .map(|t| root(&mut parent, t))
            .filter(|&r| {
                let s = size[r as usize];
                s * 50 < tets && (s < CRUMB_TETS || !deep[r as usize])
            })
            .collect();
        small.sort_unstable();
        small.dedup();
        if small.is_empty() {
            return small;
        }
        let mut out: Vec<u32> = (0..tets as u32)
            .filter(|&t| small.binary_search(&root(&mut parent, t)).is_ok())
            .collect();
        out.sort_unstable();
        out
    }

    /// For every node on a separated face: the groups of its tetrahedra still joined through
    /// faces that are not separated (the first group keeps the node).
    pub(super) fn plan_split(&self, separated: &[[u32; 3]]) -> Vec<(u32, Vec<Vec<u32>>)> {
        let mut nodes: Vec<u32> = separated.iter().flatten().copied().collect();
        nodes.sort_unstable();
        nodes.dedup();
        let mut around: HashMap<u32, Vec<u32>> = nodes.iter().map(|&v| (v, Vec::new())).collect();
        for (t, tet) in self.tets.iter().enumerate() {
            for v in tet {
                if let Some(list) = around.get_mut(v) {
                    list.push(t as u32);
                }
            }
        }
        let mut plan = Vec::with_capacity(nodes.len());
        for v in nodes {
            let tets = &around[&v];
            // Union-find over the tetrahedra around v, through the faces holding v.
            let mut parent: Vec<usize> = (0..tets.len()).collect();
            fn find(p: &mut [usize], mut i: usize) -> usize {
                while p[i] != i {
                    p[i] = p[p[i]];
                    i = p[i];
                }
                i
            }
            let mut by_face: HashMap<[u32; 3], usize> = HashMap::new();
            for (k, &t) in tets.iter().enumerate() {
                let tet = self.tets[t as usize];
                for opposite in 0..4 {
                    if tet[opposite] == v {
                        continue;
                    }
                    let key = face_key(&tet, opposite);
                    if separated.binary_search(&key).is_ok() {
                        continue;
                    }
                    if let Some(&other) = by_face.get(&key) {
                        let (ra, rb) = (find(&mut parent, k), find(&mut parent, other));
                        parent[ra.max(rb)] = ra.min(rb);
                    } else {
                        by_face.insert(key, k);
                    }
                }
            }
            let mut groups: Vec<Vec<u32>> = Vec::new();
            let mut root_group: HashMap<usize, usize> = HashMap::new();
            for (k, &t) in tets.iter().enumerate() {
                let r = find(&mut parent, k);
                let g = *root_group.entry(r).or_insert_with(|| {
                    groups.push(Vec::new());
                    groups.len() - 1
                });
                groups[g].push(t);
            }
            plan.push((v, groups));
        }
        plan
    }

    /// Edges of separated faces that would lie in more than two boundary triangles after
    /// `plan`.
    pub(super) fn non_manifold_edges(
        &self,
        plan: &[(u32, Vec<Vec<u32>>)],
        separated: &[[u32; 3]],
        holders: &HashMap<[u32; 3], Vec<(u32, u8)>>,
    ) -> Vec<(u32, u32)> {
        // The copy of node v each tetrahedron would use: (v, group index).
        let copy = |t: u32, v: u32| -> (u32, usize) {
            match plan.binary_search_by_key(&v, |(n, _)| *n) {
                Ok(k) => (
                    v,
                    plan[k].1.iter().position(|g| g.contains(&t)).unwrap_or(0),
                ),
                Err(_) => (v, 0),
            }
        };
        // Boundary triangles that hold an edge of a separated face: the separated faces'
        // sides, and the existing boundary faces there.
        let mut count: HashMap<(NodeCopy, NodeCopy), u32> = HashMap::new();
        let mut edges_of_interest: Vec<(u32, u32)> = Vec::new();
        for f in separated {
            for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[0], f[2])] {
                edges_of_interest.push((a.min(b), a.max(b)));
            }
        }
        edges_of_interest.sort_unstable();
        edges_of_interest.dedup();
        let mut add = |t: u32, tri: [u32; 3]| {
            for (a, b) in [(tri[0], tri[1]), (tri[1], tri[2]), (tri[0], tri[2])] {
                let e = (a.min(b), a.max(b));
                if edges_of_interest.binary_search(&e).is_ok() {
                    let (ca, cb) = (copy(t, e.0), copy(t, e.1));
                    *count.entry((ca, cb)).or_default() += 1;
                }
            }
        };
        for f in separated {
            for &(t, _) in &holders[f] {
                add(t, *f);
            }
        }
        // Existing boundary faces holding such an edge (every tetrahedron holding a face with
        // such an edge holds both its ends).
        let mut ends: Vec<u32> = edges_of_interest.iter().flat_map(|e| [e.0, e.1]).collect();
        ends.sort_unstable();
        ends.dedup();
        let mut face_count: HashMap<[u32; 3], (u32, u32)> = HashMap::new();
        for (t, tet) in self.tets.iter().enumerate() {
            if tet.iter().filter(|v| ends.binary_search(v).is_ok()).count() < 2 {
                continue;
            }
            for opposite in 0..4 {
                let key = face_key(tet, opposite);
                let e = face_count.entry(key).or_insert((0, t as u32));
                e.0 += 1;
            }
        }
        for (key, (n, t)) in face_count {
            if n == 1 {
                add(t, key);
            }
        }
        let mut bad: Vec<(u32, u32)> = count
            .into_iter()
            .filter(|&(_, n)| n > 2)
            .map(|(((a, _), (b, _)), _)| (a, b))
            .collect();
        bad.sort_unstable();
        bad.dedup();
        bad
    }

    /// Gives every group after the first of each planned node a copy of the node.
    pub(super) fn apply_split(&mut self, plan: Vec<(u32, Vec<Vec<u32>>)>) {
        for (v, groups) in plan {
            for group in groups.iter().skip(1) {
                let copy = self.positions.len() as u32;
                self.positions.push(self.positions[v as usize]);
                self.marked.push(self.marked[v as usize]);
                self.node_origin.push(self.node_origin[v as usize]);
                for &t in group {
                    for c in self.tets[t as usize].iter_mut() {
                        if *c == v {
                            *c = copy;
                        }
                    }
                }
            }
        }
    }

    /// The sides of the cut, each oriented outward from the tetrahedron that keeps it (with
    /// the node copies it uses now).
    pub(super) fn cut_faces(&self) -> Vec<[u32; 3]> {
        let mut out = Vec::new();
        for (tet, flags) in self.tets.iter().zip(&self.cut) {
            for (opposite, &f) in flags.iter().enumerate() {
                if f {
                    out.push(outward_face(tet, opposite, &self.positions));
                }
            }
        }
        out
    }
}
