# How many tetrahedra TetGen puts behind a decimated boundary: a closed surface decimated
# by fast-simplification's quadric collapse to a ladder of counts (distances both ways as
# in decimate_to_one_percent.py), each meshed by TetGen 1.6 with the boundary kept as given
# (-pYq1.8/8) and with Steiner points allowed on it (-pq1.8/8): tetrahedra, boundary
# triangles, smallest and largest dihedral angle. TetGen is AGPL: used here only to measure,
# nothing of it is in the project. Each TetGen run is a child process (it can crash on
# a surface that intersects itself).
#
#   pip install trimesh fast-simplification tetgen rtree   (it imports surface_distance.py, beside it)
#   python3 tetgen_behind_a_boundary.py SURFACE [COUNT,COUNT,...]
import multiprocessing as mp
import sys
from collections import Counter

import fast_simplification as fs
import numpy as np
import tetgen

from surface_distance import Reference

ref = Reference(sys.argv[1])
surf = ref.surf
two_way = ref.two_way


def dihedrals(p, t):
    out = []
    for a, b, c, d in [(0, 1, 2, 3), (0, 2, 1, 3), (0, 3, 1, 2), (1, 2, 0, 3), (1, 3, 0, 2), (2, 3, 0, 1)]:
        e = p[t[:, b]] - p[t[:, a]]
        e /= np.linalg.norm(e, axis=1)[:, None]
        u = p[t[:, c]] - p[t[:, a]]
        w = p[t[:, d]] - p[t[:, a]]
        u -= (u * e).sum(1)[:, None] * e
        w -= (w * e).sum(1)[:, None] * e
        cos = (u * w).sum(1) / np.linalg.norm(u, axis=1) / np.linalg.norm(w, axis=1)
        out.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.array(out)


def mesh(v, f, switches, q):
    try:
        nodes, elem, *_ = tetgen.TetGen(v, f).tetrahedralize(switches=switches + 'Q')
        faces = Counter()
        for t in elem[:, :4]:
            for k in [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)]:
                faces[tuple(sorted(t[list(k)]))] += 1
        boundary = sum(1 for c in faces.values() if c == 1)
        dh = dihedrals(nodes, elem[:, :4])
        q.put(' | %s: %d tets, %d boundary triangles, dihedral %.1f..%.1f' % (
            switches, len(elem), boundary, dh.min(), dh.max()))
    except Exception as e:
        q.put(' | %s: failed: %s' % (switches, str(e)[:60]))


if __name__ == '__main__':
    counts = [int(x) for x in sys.argv[2].split(',')] if len(sys.argv) > 2 else \
        [600, 800, 1000, 1200, 1400, 1600, 1800, 2000, 2200, 2500, 2800, 3200, 3600, 4000, 5000, 6000]
    name = sys.argv[1].split('/')[-1]
    for n in counts:
        if n >= len(surf.faces):
            break
        v, f = fs.simplify(surf.vertices.astype(np.float64), surf.faces.astype(np.int32), target_count=n)
        a, b = two_way(v, f)
        line = '%s %d triangles, decimated to %d: %.2f/%.2f %%' % (name, len(surf.faces), len(f), a, b)
        for switches in ['pYq1.8/8', 'pq1.8/8']:
            q = mp.Queue()
            p = mp.Process(target=mesh, args=(v, f.astype(np.int32), switches, q))
            p.start()
            p.join(300)
            line += q.get() if p.exitcode == 0 else ' | %s: crashed (exit %s)' % (switches, p.exitcode)
        print(line, flush=True)
        if max(a, b) < 0.9:
            break
