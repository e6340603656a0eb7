//! A uniform grid of a mesh's tetrahedra by their bounding boxes: what locating points in
//! the mesh ([`super::embed`]) and finding the tetrahedra near a sphere
//! ([`super::occupancy`]) search instead of every tetrahedron.

use super::TetMesh;
use crate::Vec3;

/// A mesh's tetrahedra in a uniform grid: each in every cell its bounding box meets.
#[derive(Debug, Default)]
pub(crate) struct TetGrid {
    pub(crate) origin: Vec3,
    pub(crate) cell: f64,
    pub(crate) dims: [usize; 3],
    /// Cell `c`'s tetrahedra are `items[starts[c]..starts[c + 1]]`.
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl TetGrid {
    /// About one cell per tetrahedron (at most 256 along an axis), never degenerate for a
    /// flat mesh.
    pub(crate) fn new(mesh: &TetMesh) -> Self {
        let bbox = mesh.bbox();
        let extent = bbox.extent();
        let n = mesh.tet_count().max(1) as f64;
        // About one cell per tetrahedron, never degenerate for flat meshes.
        let volume = extent.x.max(1e-12) * extent.y.max(1e-12) * extent.z.max(1e-12);
        let mut cell = (volume / n).cbrt().max(extent.max() / 256.0);
        if cell.is_nan() || cell <= 0.0 {
            cell = 1.0;
        }
        let dims = [0, 1, 2].map(|a| ((extent[a] / cell).ceil() as usize).clamp(1, 256));
        let origin = bbox.min;
        let mut grid = TetGrid {
            origin,
            cell,
            dims,
            starts: vec![0; dims[0] * dims[1] * dims[2] + 1],
            items: Vec::new(),
        };
        let ranges: Vec<[[usize; 2]; 3]> = mesh
            .tets()
            .iter()
            .map(|t| {
                let p = t.map(|i| mesh.positions()[i as usize]);
                let lo = p.iter().fold(p[0], |m, q| m.inf(q));
                let hi = p.iter().fold(p[0], |m, q| m.sup(q));
                [0, 1, 2].map(|a| [grid.index(lo[a], a), grid.index(hi[a], a)])
            })
            .collect();
        // Counting sort into the cells.
        for r in &ranges {
            grid.for_cells(r, |c, starts| starts[c + 1] += 1);
        }
        for c in 0..grid.starts.len() - 1 {
            grid.starts[c + 1] += grid.starts[c];
        }
        let mut fill = grid.starts.clone();
        grid.items = vec![0; *grid.starts.last().unwrap_or(&0) as usize];
        for (t, r) in ranges.iter().enumerate() {
            let items = &mut grid.items;
            grid_cells(grid.dims, r, |c| {
                items[fill[c] as usize] = t as u32;
                fill[c] += 1;
            });
        }
        grid
    }

    /// The cell along `axis` that holds coordinate `x` (the first or last one beyond the
    /// grid).
    pub(crate) fn index(&self, x: f64, axis: usize) -> usize {
        let i = ((x - self.origin[axis]) / self.cell).floor();
        (i.max(0.0) as usize).min(self.dims[axis].saturating_sub(1))
    }

    fn for_cells(&mut self, r: &[[usize; 2]; 3], mut f: impl FnMut(usize, &mut Vec<u32>)) {
        let starts = &mut self.starts;
        grid_cells(self.dims, r, |c| f(c, starts));
    }

    /// The tetrahedra of cell `c` (none in a grid of no cells).
    pub(crate) fn cell_items(&self, c: usize) -> &[u32] {
        if c + 1 >= self.starts.len() {
            return &[];
        }
        &self.items[self.starts[c] as usize..self.starts[c + 1] as usize]
    }
}

/// Calls `f` with the linear index of every cell in the index ranges `r`.
pub(crate) fn grid_cells(dims: [usize; 3], r: &[[usize; 2]; 3], mut f: impl FnMut(usize)) {
    for k in r[2][0]..=r[2][1] {
        for j in r[1][0]..=r[1][1] {
            for i in r[0][0]..=r[0][1] {
                f(i + dims[0] * (j + dims[1] * k));
            }
        }
    }
}
