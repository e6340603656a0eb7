# Distances between a triangle surface and another, both ways, sampled as
# `soft-tissue mesh tetrahedralize` reports them (vertices, edge midpoints and centroids),
# in % of the first surface's bounding-box diagonal, by trimesh's closest-point query.
import numpy as np
import trimesh


def samples(v, f):
    mid = lambda i, j: (v[f[:, i]] + v[f[:, j]]) / 2
    return np.concatenate([v, mid(0, 1), mid(1, 2), mid(2, 0), v[f].mean(1)])


class Reference:
    """A closed surface read from a file, to measure others against."""

    def __init__(self, path):
        self.surf = trimesh.load(path, force='mesh', process=True)
        if self.surf.volume < 0:
            self.surf.invert()
        self.diagonal = np.linalg.norm(self.surf.bounds[1] - self.surf.bounds[0])
        self.samples = samples(self.surf.vertices, self.surf.faces)

    def two_way(self, v, f):
        """(reference to (v, f), (v, f) to reference), in % of the diagonal."""
        m = trimesh.Trimesh(v, f, process=False)
        _, d1, _ = trimesh.proximity.closest_point(m, self.samples)
        _, d2, _ = trimesh.proximity.closest_point(self.surf, samples(v, f))
        return 100 * d1.max() / self.diagonal, 100 * d2.max() / self.diagonal
