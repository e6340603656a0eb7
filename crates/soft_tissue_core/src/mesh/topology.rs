//! Derived topology of a tetrahedral mesh: faces, boundary surface, edges, adjacency,
//! components. All functions are deterministic (sorting, never hash-map iteration order).

use super::MeshError;

/// Marks "no tetrahedron across this face" in [`super::TetMesh::tet_neighbors`].
pub const NO_NEIGHBOR: u32 = u32::MAX;

/// Faces of a positively oriented tet `[a, b, c, d]`, each listed so that its normal
/// `(v1 - v0) x (v2 - v0)` points out of the tet. Face `i` is opposite corner `i`.
pub(crate) const TET_FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// The boundary surface of a tetrahedral mesh.
#[derive(Debug, Clone, Default)]
pub struct Surface {
    triangles: Vec<[u32; 3]>,
    local_triangles: Vec<[u32; 3]>,
    vertices: Vec<u32>,
    volume_to_surface: Vec<u32>,
    triangle_tet: Vec<(u32, u8)>,
}

impl Surface {
    /// Boundary triangles with volume-node indices, outward-oriented (counter-clockwise seen
    /// from outside).
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// The same triangles indexing [`Surface::vertices`] (for render meshes).
    pub fn local_triangles(&self) -> &[[u32; 3]] {
        &self.local_triangles
    }

    /// Surface-to-volume vertex map: the volume node of each surface vertex, ascending.
    pub fn vertices(&self) -> &[u32] {
        &self.vertices
    }

    /// Volume-to-surface map: the surface index of a volume node, or `None` if interior.
    pub fn surface_index(&self, node: usize) -> Option<usize> {
        match self.volume_to_surface.get(node) {
            Some(&i) if i != u32::MAX => Some(i as usize),
            _ => None,
        }
    }

    /// For each triangle, the tetrahedron it bounds and the corner it is opposite to.
    pub fn triangle_tets(&self) -> &[(u32, u8)] {
        &self.triangle_tet
    }
}

/// All tet faces sorted by their (sorted) node triple.
pub(crate) struct FaceTable {
    /// (sorted nodes, tet, local face)
    entries: Vec<([u32; 3], u32, u8)>,
}

impl FaceTable {
    pub(crate) fn build(tets: &[[u32; 4]]) -> Result<Self, MeshError> {
        let entries = bucket_sorted(tets, tets.len() * 4, || {
            tets.iter().enumerate().flat_map(|(t, tet)| {
                TET_FACES.iter().enumerate().map(move |(f, face)| {
                    let mut key = face.map(|i| tet[i]);
                    key.sort_unstable();
                    (key[0], (key, t as u32, f as u8))
                })
            })
        });
        let mut i = 0;
        while i < entries.len() {
            let mut j = i + 1;
            while j < entries.len() && entries[j].0 == entries[i].0 {
                j += 1;
            }
            if j - i > 2 {
                return Err(MeshError::NonManifoldFace {
                    face: entries[i].0.map(|n| n as usize),
                    count: j - i,
                    tets: entries[i..j.min(i + 3)]
                        .iter()
                        .map(|e| e.1 as usize)
                        .collect(),
                });
            }
            i = j;
        }
        Ok(Self { entries })
    }

    /// Runs of equal faces: (start, len).
    fn groups(&self) -> impl Iterator<Item = &[([u32; 3], u32, u8)]> {
        self.entries
            .chunk_by(|a, b| a.0 == b.0)
            .filter(|g| !g.is_empty())
    }

    pub(crate) fn neighbors(&self, tet_count: usize) -> Vec<[u32; 4]> {
        let mut n = vec![[NO_NEIGHBOR; 4]; tet_count];
        for g in self.groups() {
            if let [a, b] = g {
                n[a.1 as usize][a.2 as usize] = b.1;
                n[b.1 as usize][b.2 as usize] = a.1;
            }
        }
        n
    }
}

pub(crate) fn check_duplicates(tets: &[[u32; 4]]) -> Result<(), MeshError> {
    let keys = bucket_sorted(tets, tets.len(), || {
        tets.iter().enumerate().map(|(i, t)| {
            let mut k = *t;
            k.sort_unstable();
            (k[0], (k, i))
        })
    });
    for w in keys.windows(2) {
        if w[0].0 == w[1].0 {
            return Err(MeshError::DuplicateTet {
                tet: w[1].1,
                first: w[0].1,
                nodes: w[0].0.map(|n| n as usize),
            });
        }
    }
    Ok(())
}

pub(crate) fn extract_surface(tets: &[[u32; 4]], faces: &FaceTable, node_count: usize) -> Surface {
    // Boundary faces in (tet, face) order so the output follows the input ordering.
    let mut boundary: Vec<(u32, u8)> = faces
        .groups()
        .filter(|g| g.len() == 1)
        .map(|g| (g[0].1, g[0].2))
        .collect();
    boundary.sort_unstable();
    let triangles: Vec<[u32; 3]> = boundary
        .iter()
        .map(|&(t, f)| TET_FACES[f as usize].map(|i| tets[t as usize][i]))
        .collect();
    let mut on_surface = vec![false; node_count];
    for &n in triangles.iter().flatten() {
        on_surface[n as usize] = true;
    }
    let mut volume_to_surface = vec![u32::MAX; node_count];
    let mut vertices = Vec::new();
    for (n, &s) in on_surface.iter().enumerate() {
        if s {
            volume_to_surface[n] = vertices.len() as u32;
            vertices.push(n as u32);
        }
    }
    let local_triangles = triangles
        .iter()
        .map(|t| t.map(|n| volume_to_surface[n as usize]))
        .collect();
    Surface {
        triangles,
        local_triangles,
        vertices,
        volume_to_surface,
        triangle_tet: boundary,
    }
}

pub(crate) fn edges(tets: &[[u32; 4]]) -> Vec<[u32; 2]> {
    const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
    let mut e = bucket_sorted(tets, tets.len() * 6, || {
        tets.iter().flat_map(|t| {
            PAIRS.iter().map(move |&(i, j)| {
                let (a, b) = (t[i].min(t[j]), t[i].max(t[j]));
                (a, [a, b])
            })
        })
    });
    e.dedup();
    e
}

/// The items `items()` yields, sorted ascending: the same vector `sort_unstable` would give
/// (all callers' items are distinct or, where equal, indistinguishable), in less time.
///
/// Each item comes with its lead, a node of `tets` that must be the item's first sort key
/// (items with a smaller lead sort first). A counting sort places the items in runs by lead
/// (offsets over node ids), then each short run is sorted on its own. `items` is called twice
/// (count, then place) and must yield `len` items in the same order both times.
fn bucket_sorted<T, I>(tets: &[[u32; 4]], len: usize, items: impl Fn() -> I) -> Vec<T>
where
    T: Ord + Copy + Default,
    I: Iterator<Item = (u32, T)>,
{
    let node_bound = tets.iter().flatten().max().map_or(0, |&n| n as usize + 1);
    let mut start = vec![0usize; node_bound + 1];
    for (lead, _) in items() {
        start[lead as usize + 1] += 1;
    }
    for n in 0..node_bound {
        start[n + 1] += start[n];
    }
    debug_assert_eq!(start[node_bound], len);
    let mut fill = start.clone();
    let mut sorted = vec![T::default(); len];
    for (lead, item) in items() {
        let slot = &mut fill[lead as usize];
        sorted[*slot] = item;
        *slot += 1;
    }
    for run in start.windows(2) {
        sorted[run[0]..run[1]].sort_unstable();
    }
    sorted
}

/// Node-to-tet adjacency in compressed form: offsets (len nodes + 1) and the list.
pub(crate) fn node_tets(tets: &[[u32; 4]], node_count: usize) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; node_count + 1];
    for &n in tets.iter().flatten() {
        offsets[n as usize + 1] += 1;
    }
    for i in 0..node_count {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets.clone();
    let mut list = vec![0u32; tets.len() * 4];
    for (t, tet) in tets.iter().enumerate() {
        for &n in tet {
            list[fill[n as usize] as usize] = t as u32;
            fill[n as usize] += 1;
        }
    }
    (offsets, list)
}

/// Connected components through shared nodes: per-node component id (`u32::MAX` for
/// unreferenced nodes), numbered in order of their smallest node, and the count.
pub(crate) fn components(tets: &[[u32; 4]], node_count: usize) -> (Vec<u32>, usize) {
    let mut parent: Vec<u32> = (0..node_count as u32).collect();
    fn find(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            let p = parent[parent[x as usize] as usize];
            parent[x as usize] = p;
            x = p;
        }
        x
    }
    let mut used = vec![false; node_count];
    for t in tets {
        for &n in t {
            used[n as usize] = true;
        }
        let r0 = find(&mut parent, t[0]);
        for &n in &t[1..] {
            let r = find(&mut parent, n);
            if r != r0 {
                let (lo, hi) = (r.min(r0), r.max(r0));
                parent[hi as usize] = lo;
            }
        }
    }
    let mut id = vec![u32::MAX; node_count];
    let mut root_id = vec![u32::MAX; node_count];
    let mut count = 0;
    for n in 0..node_count {
        if !used[n] {
            continue;
        }
        let r = find(&mut parent, n as u32) as usize;
        if root_id[r] == u32::MAX {
            root_id[r] = count;
            count += 1;
        }
        id[n] = root_id[r];
    }
    (id, count as usize)
}
