//! Tetrahedral meshes: storage, validation, derived topology and quality.
//!
//! A [`TetMesh`] is built from node positions and tetrahedra with [`TetMesh::new`], which
//! validates the input (typed [`MeshError`]s naming the element), re-orients inverted
//! tetrahedra and derives everything the solvers need: the outward boundary surface, the
//! unique edges, per-tet volumes, node-to-tet and tet-to-tet adjacency, connected
//! components and the bounding box. The boundary surface is always derived from the
//! tetrahedra; surface data stored in files is ignored.

mod coarsen;
mod coarsen_boundary;
pub mod cut;
pub mod embed;
pub mod generate;
pub mod io;
pub mod occupancy;
pub mod pieces;
mod quality;
pub mod subdivide;
pub mod surface_tree;
mod tet_grid;
pub mod tetrahedralize;
mod topology;

pub use quality::{QualityReport, tet_dihedral_angles, tet_radius_ratio};
pub use topology::{NO_NEIGHBOR, Surface};

use crate::Vec3;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Validation errors: the mesh cannot be used. Every variant names the element at fault.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum MeshError {
    /// The mesh has no tetrahedra at all.
    #[error("the mesh has no tetrahedra")]
    NoTetrahedra,
    /// A tetrahedron refers to a node that does not exist.
    #[error(
        "tetrahedron {tet}: corner {corner} refers to node {node}, but there are only {node_count} nodes"
    )]
    IndexOutOfRange {
        /// Index of the tetrahedron (0-based, in file order).
        tet: usize,
        /// Which of the four corners (0-3).
        corner: usize,
        /// The offending node index.
        node: usize,
        /// Number of nodes in the mesh.
        node_count: usize,
    },
    /// A tetrahedron uses the same node twice.
    #[error("tetrahedron {tet}: node {node} appears more than once in {nodes:?}")]
    RepeatedNode {
        /// Index of the tetrahedron.
        tet: usize,
        /// The repeated node.
        node: usize,
        /// The four node indices of the tetrahedron.
        nodes: [usize; 4],
    },
    /// A node coordinate is NaN or infinite.
    #[error("node {node}: coordinate {axis} is not finite ({value})")]
    NonFiniteCoordinate {
        /// Index of the node.
        node: usize,
        /// `x`, `y` or `z`.
        axis: char,
        /// The value found.
        value: f64,
    },
    /// A tetrahedron has zero or negligible volume.
    #[error(
        "tetrahedron {tet} {nodes:?} is degenerate: volume {volume:e} is {ratio:e} of a regular tetrahedron with the same edge lengths (threshold {threshold:e})"
    )]
    DegenerateTet {
        /// Index of the tetrahedron.
        tet: usize,
        /// The four node indices.
        nodes: [usize; 4],
        /// Its signed volume.
        volume: f64,
        /// Volume divided by that of a regular tetrahedron of the same RMS edge length.
        ratio: f64,
        /// The threshold in force ([`ValidationOptions::degenerate_ratio`]).
        threshold: f64,
    },
    /// Two tetrahedra use the same four nodes.
    #[error("tetrahedron {tet} duplicates tetrahedron {first} (nodes {nodes:?})")]
    DuplicateTet {
        /// Index of the later copy.
        tet: usize,
        /// Index of the first occurrence.
        first: usize,
        /// The shared nodes, sorted.
        nodes: [usize; 4],
    },
    /// A triangular face is shared by more than two tetrahedra (overlapping elements).
    #[error(
        "face {face:?} is shared by {count} tetrahedra (first {tets:?}); a face may bound at most two"
    )]
    NonManifoldFace {
        /// The face's nodes, sorted.
        face: [usize; 3],
        /// How many tetrahedra share it.
        count: usize,
        /// The first tetrahedra found sharing it (at most three).
        tets: Vec<usize>,
    },
    /// Positions given for another number of nodes than the mesh has
    /// ([`TetMesh::moved_to`]).
    #[error("positions for {given} nodes given to a mesh of {nodes}")]
    NodeCount {
        /// Positions given.
        given: usize,
        /// Nodes of the mesh.
        nodes: usize,
    },
    /// More nodes or tetrahedra than 32-bit indices can address.
    #[error("too many {what}: {count} (at most {max})")]
    TooLarge {
        /// `nodes` or `tetrahedra`.
        what: &'static str,
        /// The count found.
        count: usize,
        /// The largest supported count.
        max: usize,
    },
}

/// Facts about a mesh that do not prevent its use but that a user should know.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum MeshWarning {
    /// Tetrahedra given with negative orientation were re-oriented (two corners swapped).
    Reoriented {
        /// How many were re-oriented.
        count: usize,
        /// The first few of them.
        first: Vec<usize>,
    },
    /// Nodes not used by any tetrahedron. They are kept (indices stay valid) but have no mass
    /// and no surface; [`TetMesh::compacted`] removes them.
    UnreferencedNodes {
        /// How many.
        count: usize,
        /// The first few of them.
        first: Vec<usize>,
    },
    /// The tetrahedra form several connected pieces (connected through shared nodes).
    SeveralComponents {
        /// Number of pieces.
        count: usize,
    },
}

impl std::fmt::Display for MeshWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Reoriented { count, first } => write!(
                f,
                "{count} inverted tetrahedra were re-oriented (first: {first:?})"
            ),
            Self::UnreferencedNodes { count, first } => write!(
                f,
                "{count} nodes are not used by any tetrahedron (first: {first:?})"
            ),
            Self::SeveralComponents { count } => {
                write!(f, "the mesh has {count} connected components")
            }
        }
    }
}

/// Thresholds used by [`TetMesh::with_options`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ValidationOptions {
    /// A tetrahedron whose |volume| is below this fraction of the volume of a regular
    /// tetrahedron with the same RMS edge length is rejected as degenerate. Dimensionless,
    /// default `1e-6` (a well-shaped element is above `0.1`; FEM becomes unusable long before
    /// `1e-6`).
    pub degenerate_ratio: f64,
}

impl Default for ValidationOptions {
    fn default() -> Self {
        Self {
            degenerate_ratio: 1e-6,
        }
    }
}

/// Axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    /// Smallest coordinates.
    pub min: Vec3,
    /// Largest coordinates.
    pub max: Vec3,
}

impl Aabb {
    /// The box around a set of points; `None` when there are none.
    pub fn from_points<'a>(points: impl IntoIterator<Item = &'a Vec3>) -> Option<Self> {
        let mut it = points.into_iter();
        let first = *it.next()?;
        let mut b = Aabb {
            min: first,
            max: first,
        };
        for p in it {
            b.min = b.min.inf(p);
            b.max = b.max.sup(p);
        }
        Some(b)
    }

    /// Edge lengths along x, y, z.
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// Smallest edge length (the paper measures errors against it).
    pub fn smallest_dimension(&self) -> f64 {
        self.extent().min()
    }

    /// Length of the diagonal.
    pub fn diagonal(&self) -> f64 {
        self.extent().norm()
    }

    /// Centre point.
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }
}

/// A validated tetrahedral mesh with its derived topology.
///
/// Node indices and tetrahedra are stored as `u32`. All tetrahedra have positive orientation:
/// `(p1 - p0) . ((p2 - p0) x (p3 - p0)) > 0`.
#[derive(Debug, Clone)]
pub struct TetMesh {
    positions: Vec<Vec3>,
    tets: Vec<[u32; 4]>,
    volumes: Vec<f64>,
    surface: Surface,
    edges: Vec<[u32; 2]>,
    node_tet_offsets: Vec<u32>,
    node_tet_list: Vec<u32>,
    tet_neighbors: Vec<[u32; 4]>,
    node_component: Vec<u32>,
    component_count: usize,
    bbox: Aabb,
    warnings: Vec<MeshWarning>,
}

const MAX_LISTED: usize = 10;

impl TetMesh {
    /// Builds and validates a mesh with the default [`ValidationOptions`].
    pub fn new(positions: Vec<Vec3>, tets: Vec<[usize; 4]>) -> Result<Self, MeshError> {
        Self::with_options(positions, tets, &ValidationOptions::default())
    }

    /// Builds and validates a mesh.
    ///
    /// Errors (first found, in this order): no tetrahedra, too many nodes, non-finite
    /// coordinates, indices out of range, repeated nodes in a tet, degenerate tets, duplicate
    /// tets, faces shared by more than two tets. Inverted tets are re-oriented and reported as a
    /// [`MeshWarning`], as are unreferenced nodes and several connected components.
    pub fn with_options(
        positions: Vec<Vec3>,
        tets: Vec<[usize; 4]>,
        options: &ValidationOptions,
    ) -> Result<Self, MeshError> {
        if tets.is_empty() {
            return Err(MeshError::NoTetrahedra);
        }
        let max = u32::MAX as usize - 1;
        if positions.len() > max {
            return Err(MeshError::TooLarge {
                what: "nodes",
                count: positions.len(),
                max,
            });
        }
        if tets.len() > max {
            return Err(MeshError::TooLarge {
                what: "tetrahedra",
                count: tets.len(),
                max,
            });
        }
        for (node, p) in positions.iter().enumerate() {
            for (axis, value) in ['x', 'y', 'z'].into_iter().zip(p.iter()) {
                if !value.is_finite() {
                    return Err(MeshError::NonFiniteCoordinate {
                        node,
                        axis,
                        value: *value,
                    });
                }
            }
        }
        let node_count = positions.len();
        let mut oriented = Vec::with_capacity(tets.len());
        let mut volumes = Vec::with_capacity(tets.len());
        let mut reoriented = Vec::new();
        for (t, nodes) in tets.iter().enumerate() {
            for (corner, &node) in nodes.iter().enumerate() {
                if node >= node_count {
                    return Err(MeshError::IndexOutOfRange {
                        tet: t,
                        corner,
                        node,
                        node_count,
                    });
                }
            }
            for i in 0..4 {
                for j in i + 1..4 {
                    if nodes[i] == nodes[j] {
                        return Err(MeshError::RepeatedNode {
                            tet: t,
                            node: nodes[i],
                            nodes: *nodes,
                        });
                    }
                }
            }
            let p = nodes.map(|n| positions[n]);
            let volume = tet_signed_volume(&p);
            let ratio = volume_ratio(&p, volume);
            if ratio.is_nan() || ratio.abs() < options.degenerate_ratio {
                return Err(MeshError::DegenerateTet {
                    tet: t,
                    nodes: *nodes,
                    volume,
                    ratio,
                    threshold: options.degenerate_ratio,
                });
            }
            let mut n = nodes.map(|v| v as u32);
            if volume < 0.0 {
                n.swap(1, 2);
                reoriented.push(t);
            }
            oriented.push(n);
            volumes.push(volume.abs());
        }
        topology::check_duplicates(&oriented)?;
        let faces = topology::FaceTable::build(&oriented)?;
        let surface = topology::extract_surface(&oriented, &faces, node_count);
        let tet_neighbors = faces.neighbors(oriented.len());
        let edges = topology::edges(&oriented);
        let (node_tet_offsets, node_tet_list) = topology::node_tets(&oriented, node_count);
        let (node_component, component_count) = topology::components(&oriented, node_count);

        let mut warnings = Vec::new();
        if !reoriented.is_empty() {
            let count = reoriented.len();
            reoriented.truncate(MAX_LISTED);
            warnings.push(MeshWarning::Reoriented {
                count,
                first: reoriented,
            });
        }
        let unreferenced: Vec<usize> = (0..node_count)
            .filter(|&n| node_tet_offsets[n] == node_tet_offsets[n + 1])
            .collect();
        if !unreferenced.is_empty() {
            warnings.push(MeshWarning::UnreferencedNodes {
                count: unreferenced.len(),
                first: unreferenced.iter().copied().take(MAX_LISTED).collect(),
            });
        }
        if component_count > 1 {
            warnings.push(MeshWarning::SeveralComponents {
                count: component_count,
            });
        }
        // Returned to the caller (`TetMesh::warnings`), who shows them: logged at debug
        // level only, so a logger does not show each twice.
        for w in &warnings {
            log::debug!("{w}");
        }
        let referenced = oriented.iter().flatten().map(|&n| &positions[n as usize]);
        let bbox = Aabb::from_points(referenced).expect("at least one tetrahedron");
        Ok(Self {
            positions,
            tets: oriented,
            volumes,
            surface,
            edges,
            node_tet_offsets,
            node_tet_list,
            tet_neighbors,
            node_component,
            component_count,
            bbox,
            warnings,
        })
    }

    /// Node rest positions.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// Tetrahedra (positively oriented).
    pub fn tets(&self) -> &[[u32; 4]] {
        &self.tets
    }

    /// Number of nodes (including unreferenced ones).
    pub fn node_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of tetrahedra.
    pub fn tet_count(&self) -> usize {
        self.tets.len()
    }

    /// Rest volume of each tetrahedron (positive).
    pub fn tet_volumes(&self) -> &[f64] {
        &self.volumes
    }

    /// Total rest volume.
    pub fn volume(&self) -> f64 {
        self.volumes.iter().sum()
    }

    /// The boundary surface (outward-oriented triangles).
    pub fn surface(&self) -> &Surface {
        &self.surface
    }

    /// Unique edges, each as `[a, b]` with `a < b`, sorted.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }

    /// Tetrahedra that use `node`.
    pub fn node_tets(&self, node: usize) -> &[u32] {
        let a = self.node_tet_offsets[node] as usize;
        let b = self.node_tet_offsets[node + 1] as usize;
        &self.node_tet_list[a..b]
    }

    /// For each tet, the tet across the face opposite each corner, or [`NO_NEIGHBOR`].
    pub fn tet_neighbors(&self) -> &[[u32; 4]] {
        &self.tet_neighbors
    }

    /// Number of connected components (through shared nodes).
    pub fn component_count(&self) -> usize {
        self.component_count
    }

    /// Component id of each node; unreferenced nodes get `u32::MAX`.
    pub fn node_components(&self) -> &[u32] {
        &self.node_component
    }

    /// This mesh with every node moved by `map`, a map that keeps each element's orientation
    /// (a placement: rotation, translation, positive scale). The topology is kept; only the
    /// volumes and the bounds are computed again, in time linear in the mesh. An error where a
    /// moved coordinate is not finite or an element's volume is not positive (the map turned
    /// it inside out or flattened it: [`TetMesh::new`] builds such a mesh anew).
    pub fn mapped(&self, map: impl Fn(&Vec3) -> Vec3) -> Result<TetMesh, MeshError> {
        let positions: Vec<Vec3> = self.positions.iter().map(map).collect();
        self.relocated(positions, 0.0)
    }

    /// This mesh with its nodes at `positions` (one per node, in order; a deformed state of
    /// it, say): the topology is kept and only the volumes and the bounds are computed again,
    /// in time linear in the mesh, where [`TetMesh::new`] would derive the faces, edges and
    /// neighbours anew. Refused as [`TetMesh::new`] would refuse or turn over an element:
    /// an error where a coordinate is not finite, an element is inverted or flat, or flatter
    /// than [`ValidationOptions::default`]'s `degenerate_ratio`.
    pub fn moved_to(&self, positions: Vec<Vec3>) -> Result<TetMesh, MeshError> {
        if positions.len() != self.positions.len() {
            return Err(MeshError::NodeCount {
                given: positions.len(),
                nodes: self.positions.len(),
            });
        }
        self.relocated(positions, ValidationOptions::default().degenerate_ratio)
    }

    /// This mesh's topology at `positions` (as many as its nodes); an element whose volume
    /// is not positive, or whose volume ratio is below `min_ratio`, is an error.
    fn relocated(&self, positions: Vec<Vec3>, min_ratio: f64) -> Result<TetMesh, MeshError> {
        for (node, p) in positions.iter().enumerate() {
            for (axis, name) in ['x', 'y', 'z'].into_iter().enumerate() {
                if !p[axis].is_finite() {
                    return Err(MeshError::NonFiniteCoordinate {
                        node,
                        axis: name,
                        value: p[axis],
                    });
                }
            }
        }
        let mut volumes = Vec::with_capacity(self.tets.len());
        for (tet, t) in self.tets.iter().enumerate() {
            let corners = t.map(|i| positions[i as usize]);
            let volume = tet_signed_volume(&corners);
            // (A ratio that is not a number, from coordinates whose volume overflows, is
            // refused as `new` refuses it.)
            let ratio = volume_ratio(&corners, volume);
            if volume.is_nan() || volume <= 0.0 || ratio.is_nan() || ratio < min_ratio {
                let mut sum = 0.0;
                for a in 0..4 {
                    for b in a + 1..4 {
                        sum += (corners[a] - corners[b]).norm_squared();
                    }
                }
                let edge = (sum / 6.0).sqrt();
                return Err(MeshError::DegenerateTet {
                    tet,
                    nodes: t.map(|i| i as usize),
                    volume,
                    ratio: volume / (edge.powi(3) / (6.0 * std::f64::consts::SQRT_2)),
                    threshold: min_ratio,
                });
            }
            volumes.push(volume);
        }
        let bbox = Aabb::from_points(self.tets.iter().flatten().map(|&n| &positions[n as usize]))
            .unwrap_or(self.bbox);
        Ok(TetMesh {
            positions,
            tets: self.tets.clone(),
            volumes,
            surface: self.surface.clone(),
            edges: self.edges.clone(),
            node_tet_offsets: self.node_tet_offsets.clone(),
            node_tet_list: self.node_tet_list.clone(),
            tet_neighbors: self.tet_neighbors.clone(),
            node_component: self.node_component.clone(),
            component_count: self.component_count,
            bbox,
            // The topology's warnings hold; elements turned over when the mesh was built
            // are not turned over at these positions.
            warnings: self
                .warnings
                .iter()
                .filter(|w| !matches!(w, MeshWarning::Reoriented { .. }))
                .cloned()
                .collect(),
        })
    }

    /// Bounding box of the nodes used by tetrahedra.
    pub fn bbox(&self) -> Aabb {
        self.bbox
    }

    /// Warnings found while building the mesh.
    pub fn warnings(&self) -> &[MeshWarning] {
        &self.warnings
    }

    /// Element quality statistics.
    pub fn quality(&self) -> QualityReport {
        QualityReport::compute(&self.positions, &self.tets)
    }

    /// A copy without unreferenced nodes, and for each old node its new index (or `None`).
    pub fn compacted(&self) -> Result<(TetMesh, Vec<Option<usize>>), MeshError> {
        let mut used = vec![false; self.positions.len()];
        for &n in self.tets.iter().flatten() {
            used[n as usize] = true;
        }
        let mut map = vec![None; self.positions.len()];
        let mut positions = Vec::new();
        for (old, p) in self.positions.iter().enumerate() {
            if used[old] {
                map[old] = Some(positions.len());
                positions.push(*p);
            }
        }
        let tets = self
            .tets
            .iter()
            .map(|t| t.map(|n| map[n as usize].expect("referenced")))
            .collect();
        Ok((TetMesh::new(positions, tets)?, map))
    }
}

/// Signed volume of a tetrahedron: `(p1-p0) . ((p2-p0) x (p3-p0)) / 6`.
pub fn tet_signed_volume(p: &[Vec3; 4]) -> f64 {
    let a = p[1] - p[0];
    let b = p[2] - p[0];
    let c = p[3] - p[0];
    a.dot(&b.cross(&c)) / 6.0
}

/// Volume divided by the volume of a regular tetrahedron with the same RMS edge length
/// (1 for a regular tetrahedron, 0 for a flat one; the sign follows orientation).
fn volume_ratio(p: &[Vec3; 4], volume: f64) -> f64 {
    let mut sum = 0.0;
    for i in 0..4 {
        for j in i + 1..4 {
            sum += (p[i] - p[j]).norm_squared();
        }
    }
    let l_rms = (sum / 6.0).sqrt();
    let regular = l_rms.powi(3) / (6.0 * std::f64::consts::SQRT_2);
    if regular > 0.0 { volume / regular } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_tet() -> (Vec<Vec3>, Vec<[usize; 4]>) {
        (
            vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.0, 0.0, 1.0),
            ],
            vec![[0, 1, 2, 3]],
        )
    }

    #[test]
    fn single_tet_has_four_outward_faces() {
        let (p, t) = unit_tet();
        let m = TetMesh::new(p, t).unwrap();
        assert_eq!(m.surface().triangles().len(), 4);
        assert_eq!(m.edges().len(), 6);
        assert!((m.volume() - 1.0 / 6.0).abs() < 1e-15);
        let c = Vec3::new(0.25, 0.25, 0.25);
        for tri in m.surface().triangles() {
            let [a, b, d] = tri.map(|i| m.positions()[i as usize]);
            let n = (b - a).cross(&(d - a));
            assert!(n.dot(&(a - c)) > 0.0, "face {tri:?} points inwards");
        }
        assert!(m.warnings().is_empty());
    }

    #[test]
    fn inverted_tet_is_reoriented_with_warning() {
        let (p, _) = unit_tet();
        let m = TetMesh::new(p, vec![[0, 2, 1, 3]]).unwrap();
        assert!(matches!(
            m.warnings()[0],
            MeshWarning::Reoriented { count: 1, .. }
        ));
        let t = m.tets()[0].map(|i| m.positions()[i as usize]);
        assert!(tet_signed_volume(&t) > 0.0);
    }

    #[test]
    fn errors_name_the_element() {
        let (p, _) = unit_tet();
        let e = TetMesh::new(p.clone(), vec![[0, 1, 2, 7]]).unwrap_err();
        assert_eq!(
            e,
            MeshError::IndexOutOfRange {
                tet: 0,
                corner: 3,
                node: 7,
                node_count: 4
            }
        );
        let e = TetMesh::new(p.clone(), vec![[0, 1, 2, 3], [3, 2, 1, 0]]).unwrap_err();
        assert!(matches!(
            e,
            MeshError::DuplicateTet {
                tet: 1,
                first: 0,
                ..
            }
        ));
        let e = TetMesh::new(p.clone(), vec![[0, 1, 1, 3]]).unwrap_err();
        assert!(matches!(
            e,
            MeshError::RepeatedNode {
                tet: 0,
                node: 1,
                ..
            }
        ));
        let mut flat = p.clone();
        flat[3] = Vec3::new(0.3, 0.3, 0.0);
        let e = TetMesh::new(flat, vec![[0, 1, 2, 3]]).unwrap_err();
        assert!(matches!(e, MeshError::DegenerateTet { tet: 0, .. }));
        let mut nan = p;
        nan[2].y = f64::NAN;
        let e = TetMesh::new(nan, vec![[0, 1, 2, 3]]).unwrap_err();
        assert!(matches!(
            e,
            MeshError::NonFiniteCoordinate {
                node: 2,
                axis: 'y',
                ..
            }
        ));
        assert_eq!(
            TetMesh::new(vec![], vec![]).unwrap_err(),
            MeshError::NoTetrahedra
        );
    }

    #[test]
    fn unreferenced_nodes_and_components_are_reported() {
        let (mut p, mut t) = unit_tet();
        p.push(Vec3::new(9.0, 9.0, 9.0)); // 4: unused
        for d in [Vec3::new(5.0, 0.0, 0.0); 4].iter().zip(0..4) {
            p.push(p[d.1] + d.0);
        }
        t.push([5, 6, 7, 8]);
        let m = TetMesh::new(p, t).unwrap();
        assert_eq!(m.component_count(), 2);
        assert!(m.warnings().iter().any(|w| matches!(
            w,
            MeshWarning::UnreferencedNodes { count: 1, first } if first == &vec![4]
        )));
        assert_eq!(m.node_components()[4], u32::MAX);
        let (c, map) = m.compacted().unwrap();
        assert_eq!(c.node_count(), 8);
        assert_eq!(map[4], None);
        assert_eq!(map[5], Some(4));
        // the bounding box ignores the unused node
        assert!((m.bbox().max.x - 6.0).abs() < 1e-12);
    }

    #[test]
    fn face_shared_by_three_tets_is_an_error() {
        let p = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.2, 0.2, 1.0),
            Vec3::new(0.2, 0.2, -1.0),
            Vec3::new(0.3, 0.3, 2.0),
        ];
        let e = TetMesh::new(p, vec![[0, 1, 2, 3], [0, 2, 1, 4], [0, 1, 2, 5]]).unwrap_err();
        assert!(matches!(e, MeshError::NonManifoldFace { count: 3, .. }));
    }
}
