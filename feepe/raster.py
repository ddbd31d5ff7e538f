"""A rasteriser for the silhouette refinement, on the CPU: a mesh's depth at pixel centres (a z-buffer),
and whether sub-pixel image points fall on it.

The refinement renders the model's mask many times per frame (to rank starting poses by mask IoU) and asks,
for every contour point, whether the image just outside it misses the robot. Casting rays through
trimesh's Embree binding spends most of its time in per-call and per-ray overhead; the same answers come
from the projected triangles, scan converted (or binned into image cells) by code that numba compiles.
Pixel centres sit at integer (u, v), as in OpenCV; depth is interpolated as 1/z, which is linear in the
image. Triangles are clipped at a near plane, so a part that reaches behind the camera keeps what lies
in front. `clustered` makes the coarse copy of a mesh that the refinement's coarse stages render.
"""

from __future__ import annotations

import numba
import numpy as np

NEAR_M = 0.01  # the near clipping plane (m)
CELL_PX = 1  # side of the image cells that `covered` bins triangles into


@numba.njit(cache=True, nogil=True)
def _clip(P, face, poly):
    """The face's corners in front of z = NEAR_M into `poly` (Sutherland-Hodgman against one plane);
    returns their number: 0, 3 or 4."""
    n = 0
    for k in range(3):
        p, q = P[face[k]], P[face[(k + 1) % 3]]
        if p[2] >= NEAR_M:
            poly[n] = p
            n += 1
        if (p[2] >= NEAR_M) != (q[2] >= NEAR_M):
            if q[2] >= NEAR_M:  # from the corner in front, so the face beside gets the very same point
                p, q = q, p
            poly[n] = p + (NEAR_M - p[2]) / (q[2] - p[2]) * (q - p)
            n += 1
    return n


@numba.njit(cache=True, nogil=True, inline="always")
def to_pixel(fx, fy, cx, cy, x, y, z):
    """Camera point (x, y, z) -> pixel (u, v): `kernel.camera.project` in scalars, for compiled loops."""
    return fx * x / z + cx, fy * y / z + cy


@numba.njit(cache=True, nogil=True, parallel=True)
def _pixels(P, fx, fy, cx, cy):
    uv = np.empty((P.shape[0], 2))
    for i in numba.prange(P.shape[0]):
        uv[i, 0], uv[i, 1] = to_pixel(fx, fy, cx, cy, P[i, 0], P[i, 1], max(P[i, 2], NEAR_M))
    return uv


@numba.njit(cache=True, nogil=True, parallel=True)
def _project(P, faces, fx, fy, cx, cy):
    """Image triangles (T, 3, 2) and their corners' depths (T, 3): a face wholly in front of the near plane
    stays one triangle, one cut by it becomes one or two (a fan over the clipped polygon). When no face is
    cut (the usual case), face f is triangle f, written on both cores."""
    uv = _pixels(P, fx, fy, cx, cy)
    front = np.empty(faces.shape[0], np.bool_)
    for f in numba.prange(faces.shape[0]):
        front[f] = P[faces[f, 0], 2] >= NEAR_M and P[faces[f, 1], 2] >= NEAR_M and P[faces[f, 2], 2] >= NEAR_M
    n_cut = faces.shape[0] - np.count_nonzero(front)
    tri, tz = np.empty((faces.shape[0] + n_cut, 3, 2)), np.empty((faces.shape[0] + n_cut, 3))
    if n_cut == 0:
        for f in numba.prange(faces.shape[0]):
            _whole_face(uv, P, faces, f, tri, tz, f)
        return tri, tz
    poly = np.empty((4, 3))
    m = 0
    for f in range(faces.shape[0]):
        if front[f]:
            _whole_face(uv, P, faces, f, tri, tz, m)
            m += 1
            continue
        n = _clip(P, faces[f], poly)
        for k in range(1, n - 1):
            for j, i in enumerate((0, k, k + 1)):
                tri[m, j, 0], tri[m, j, 1] = to_pixel(fx, fy, cx, cy, poly[i, 0], poly[i, 1], poly[i, 2])
                tz[m, j] = poly[i, 2]
            m += 1
    return tri[:m], tz[:m]


@numba.njit(cache=True, nogil=True, inline="always")
def _whole_face(uv, P, faces, f, tri, tz, m):
    """Face f, wholly in front of the near plane, as image triangle m."""
    for j in range(3):
        tri[m, j, 0], tri[m, j, 1], tz[m, j] = uv[faces[f, j], 0], uv[faces[f, j], 1], P[faces[f, j], 2]


@numba.njit(cache=True, nogil=True)
def _edge(xp, yp, xq, yq, u, v):
    """Twice the signed area of (p, q, (u, v)). The same edge seen from its other triangle, (q, p), gives
    exactly the negated value in floating point, so a point on a shared edge belongs to one triangle or
    both, never to none (no cracks along the diagonals of a mesh)."""
    return (xp - u) * (yq - v) - (xq - u) * (yp - v)


@numba.njit(cache=True, nogil=True)
def _weights(t, u, v):
    """The edge functions of image point (u, v) in triangle t (3, 2), signed so that all three are >= 0
    inside (edges included) and summing to twice its area; a degenerate triangle gives -1s."""
    area = _edge(t[0, 0], t[0, 1], t[1, 0], t[1, 1], t[2, 0], t[2, 1])
    if area == 0.0:
        return -1.0, -1.0, -1.0
    s = 1.0 if area > 0.0 else -1.0
    return (s * _edge(t[1, 0], t[1, 1], t[2, 0], t[2, 1], u, v), s * _edge(t[2, 0], t[2, 1], t[0, 0], t[0, 1], u, v),
            s * _edge(t[0, 0], t[0, 1], t[1, 0], t[1, 1], u, v))


@numba.njit(cache=True, nogil=True)
def _inside(t, u, v):
    """Whether image point (u, v) lies in triangle t (3, 2), edges included; a degenerate one covers nothing."""
    wa, wb, wc = _weights(t, u, v)
    return wa >= 0.0 and wb >= 0.0 and wc >= 0.0


@numba.njit(cache=True, nogil=True)
def _pixel_box(t, h, w):
    """The pixel centres a triangle's bounding box holds: first and last column, first and last row."""
    u0, u1 = np.ceil(min(t[0, 0], t[1, 0], t[2, 0])), np.floor(max(t[0, 0], t[1, 0], t[2, 0]))
    v0, v1 = np.ceil(min(t[0, 1], t[1, 1], t[2, 1])), np.floor(max(t[0, 1], t[1, 1], t[2, 1]))
    return max(int(u0), 0), min(int(u1), w - 1), max(int(v0), 0), min(int(v1), h - 1)


@numba.njit(cache=True, nogil=True, parallel=True)
def _zbuffer(tri, tz, out, ids, label):
    """Image triangles with their corners' depths into the depth image `out`, nearest kept (0: empty), and
    `label` into `ids` wherever they are drawn nearest (`ids` of no rows: none kept); the image's upper and lower
    halves on the two cores, each pixel drawn by one, in the triangles' order."""
    h = out.shape[0]
    for half in numba.prange(2):
        _zbuffer_rows(tri, tz, out, ids, label, half * (h // 2), h if half else h // 2)


@numba.njit(cache=True, nogil=True)
def _zbuffer_rows(tri, tz, out, ids, label, row_from, row_to):
    """`_zbuffer` for the image rows [row_from, row_to)."""
    h, w = out.shape
    labelled = ids.shape[0] > 0
    for i in range(tri.shape[0]):
        u0, u1, v0, v1 = _pixel_box(tri[i], h, w)
        # most triangles of a fine mesh hold no pixel centre
        for v in range(max(v0, row_from), min(v1, row_to - 1) + 1):
            for u in range(u0, u1 + 1):
                wa, wb, wc = _weights(tri[i], u, v)
                if wa < 0.0 or wb < 0.0 or wc < 0.0:
                    continue
                d = (wa + wb + wc) / (wa / tz[i, 0] + wb / tz[i, 1] + wc / tz[i, 2])
                if out[v, u] == 0.0 or d < out[v, u]:
                    out[v, u] = d
                    if labelled:
                        ids[v, u] = label


@numba.njit(cache=True, nogil=True, parallel=True)
def _cover(tri, out):
    """Image triangles into the mask `out` (pixel centres, edges included), on both cores: two triangles may
    set one pixel at once, and both set it True."""
    h, w = out.shape
    for i in numba.prange(tri.shape[0]):
        u0, u1, v0, v1 = _pixel_box(tri[i], h, w)
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                if not out[v, u] and _inside(tri[i], u, v):
                    out[v, u] = True


@numba.njit(cache=True, nogil=True, parallel=True)
def _covered(tri, uv, h, w, cell):
    """For each point, whether a triangle covers it, on both cores: the points split into two bands of
    image rows with half of them each, and each band answered by `_covered_band`."""
    rows = np.sort(np.array([uv[j, 1] for j in range(uv.shape[0]) if 0.0 <= uv[j, 1] < h]))
    split = int(rows[len(rows) // 2] / cell) if len(rows) else 0
    bands = np.array([0, split, (h + cell - 1) // cell])
    out = np.zeros(uv.shape[0], np.bool_)
    for b in numba.prange(2):
        _covered_band(tri, uv, h, w, cell, bands[b], bands[b + 1], out)
    return out


@numba.njit(cache=True, nogil=True)
def _covered_band(tri, uv, h, w, cell, row_from, row_to, out):
    """`out` for the points in cell rows [row_from, row_to): the triangles that reach an image cell holding a
    point are binned into those cells (CSR lists), and each point tests its cell's, by bounding box first. The
    cells are those of the points' bounding box, not the image's (an outline spans a small part of it), and a
    summed table of the wanted ones passes over the many triangles that reach none in four lookups each."""
    cw = (w + cell - 1) // cell
    r_lo, r_hi, c_lo, c_hi = row_to, row_from - 1, cw, -1  # the points' cells' bounding box
    for j in range(uv.shape[0]):
        if 0.0 <= uv[j, 0] < w and 0.0 <= uv[j, 1] < h and row_from <= int(uv[j, 1] / cell) < row_to:
            r, c = int(uv[j, 1] / cell), int(uv[j, 0] / cell)
            r_lo, r_hi, c_lo, c_hi = min(r_lo, r), max(r_hi, r), min(c_lo, c), max(c_hi, c)
    if r_hi < r_lo:
        return
    bh, bw = r_hi - r_lo + 1, c_hi - c_lo + 1
    wanted = np.zeros(bh * bw, np.bool_)  # box cells, row-major
    for j in range(uv.shape[0]):
        if 0.0 <= uv[j, 0] < w and 0.0 <= uv[j, 1] < h and row_from <= int(uv[j, 1] / cell) < row_to:
            wanted[(int(uv[j, 1] / cell) - r_lo) * bw + int(uv[j, 0] / cell) - c_lo] = True
    table = np.zeros((bh + 1, bw + 1), np.int32)  # table[r, c]: wanted box cells in rows < r, columns < c
    for cv in range(bh):
        for cu in range(bw):
            table[cv + 1, cu + 1] = table[cv, cu + 1] + table[cv + 1, cu] - table[cv, cu] + wanted[cv * bw + cu]
    near = np.empty(tri.shape[0], np.int64)  # the triangles that reach a wanted cell, and their boxes:
    box = np.empty((tri.shape[0], 4))  # rows written only for those (of a fine mesh, a few)
    cells = np.empty((tri.shape[0], 4), np.int64)  # first and last box column, first and last box row
    count = np.zeros(bh * bw + 1, np.int64)
    m = 0
    for i in range(tri.shape[0]):
        t = tri[i]
        u0, u1 = min(t[0, 0], t[1, 0], t[2, 0]), max(t[0, 0], t[1, 0], t[2, 0])
        v0, v1 = min(t[0, 1], t[1, 1], t[2, 1]), max(t[0, 1], t[1, 1], t[2, 1])
        if u1 < 0.0 or u0 >= w or v1 < 0.0 or v0 >= h:
            continue
        c0, c1 = max(int(max(u0, 0.0) / cell), c_lo) - c_lo, min(int(u1 / cell), c_hi) - c_lo
        r0, r1 = max(int(max(v0, 0.0) / cell), r_lo) - r_lo, min(int(v1 / cell), r_hi) - r_lo
        if c0 > c1 or r0 > r1 or table[r1 + 1, c1 + 1] - table[r0, c1 + 1] - table[r1 + 1, c0] + table[r0, c0] == 0:
            continue
        near[m] = i
        box[m, 0], box[m, 1], box[m, 2], box[m, 3] = u0, u1, v0, v1
        cells[m, 0], cells[m, 1], cells[m, 2], cells[m, 3] = c0, c1, r0, r1
        for cv in range(r0, r1 + 1):
            for cu in range(c0, c1 + 1):
                if wanted[cv * bw + cu]:
                    count[cv * bw + cu + 1] += 1
        m += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    ids = np.empty(start[-1], np.int64)  # positions in `near`
    for k in range(m):
        for cv in range(cells[k, 2], cells[k, 3] + 1):
            for cu in range(cells[k, 0], cells[k, 1] + 1):
                c = cv * bw + cu
                if wanted[c]:
                    ids[fill[c]] = k
                    fill[c] += 1
    for j in range(uv.shape[0]):
        u, v = uv[j, 0], uv[j, 1]
        if not (0.0 <= u < w and 0.0 <= v < h and row_from <= int(v / cell) < row_to):
            continue
        c = (int(v / cell) - r_lo) * bw + int(u / cell) - c_lo
        for q in range(start[c], start[c + 1]):
            k = ids[q]
            if box[k, 0] <= u <= box[k, 1] and box[k, 2] <= v <= box[k, 3] and _inside(tri[near[k]], u, v):
                out[j] = True
                break


def clustered(vertices: np.ndarray, faces: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A coarse copy of a mesh by vertex clustering (Rossignac and Borrel 1993): the vertices in each
    `cell_m` cube become their mean, faces that collapse go. Its outline stays within a cell of the
    original's, and it holds as few faces as the cells the surface crosses allow."""
    _, group, count = np.unique(np.floor(vertices / cell_m).astype(np.int64), axis=0, return_inverse=True,
                                return_counts=True)
    group = group.ravel()
    merged = np.zeros((len(count), 3))
    np.add.at(merged, group, vertices)
    merged /= count[:, None]
    f = group[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    _, first = np.unique(np.sort(f, 1), axis=0, return_index=True)  # one face per corner set, winding kept
    return merged, np.ascontiguousarray(f[np.sort(first)])


def triangles(vertices: np.ndarray, faces: np.ndarray, T_cam_model: np.ndarray,
              K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh (model-frame vertices in metres, faces int64) seen at `T_cam_model`: image triangles
    (T, 3, 2) and their corners' depths (T, 3), clipped at the near plane."""
    P = vertices @ T_cam_model[:3, :3].T + T_cam_model[:3, 3]
    return _project(P, faces, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))


_NO_IDS = np.zeros((0, 0), np.int64)


def draw_depth(out: np.ndarray, vertices: np.ndarray, faces: np.ndarray, T_cam_model: np.ndarray,
               K: np.ndarray, ids: np.ndarray | None = None, label: int = 0) -> np.ndarray:
    """Draws the mesh seen at `T_cam_model` into the depth image `out` (H, W) where it is nearer than
    what `out` holds (0: nothing drawn yet), and `label` into `ids` (H, W) int64 where it is drawn; returns
    `out`. A pixel two meshes reach at the very same depth keeps the one drawn first."""
    _zbuffer(*triangles(vertices, faces, T_cam_model, K), out, _NO_IDS if ids is None else ids, label)
    return out


def mask(tri: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The pixel centres that image triangles (T, 3, 2) cover."""
    out = np.zeros(shape, bool)
    _cover(np.ascontiguousarray(tri), out)
    return out


def silhouette(vertices: np.ndarray, faces: np.ndarray, T_cam_model: np.ndarray, K: np.ndarray,
               shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the pixel centres the mesh seen at `T_cam_model` covers (what lies behind the near plane
    cut off)."""
    return mask(triangles(vertices, faces, T_cam_model, K)[0], shape)


def render_depth(vertices: np.ndarray, faces: np.ndarray, T_cam_model: np.ndarray, K: np.ndarray,
                 shape: tuple[int, int]) -> np.ndarray:
    """The mesh's depth at pixel centres (m along the optical axis, 0 off the mesh)."""
    return draw_depth(np.zeros(shape), vertices, faces, T_cam_model, K)


def covered(tri: np.ndarray, uv: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Which image points (sub-pixel, not pixel centres; inside the image) the image triangles cover."""
    return _covered(np.ascontiguousarray(tri), np.ascontiguousarray(uv, dtype=float), shape[0], shape[1], CELL_PX)
