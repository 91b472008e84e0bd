"""Compiled per-Gaussian work of the default renderer: EWA projection, SH colours and footprints, and their gradients.

The equations are those of :func:`roodi_toolkit.render.projection.project_gaussians` and
:func:`roodi_toolkit.sh.eval_sh_colors` (the torch code the reference renderer differentiates with autograd), written
out per Gaussian with their hand-derived derivatives; the tests check both against autograd in float64 and the whole
renderer against the dense reference. Work is in float64 whatever the arrays' dtype, except the scales and opacities
(:func:`activations`, numpy's vectorised ``exp`` in the inputs' dtype, as the torch reference computes them).

- rotation ``R`` of the normalised quaternion (w, x, y, z; zero gives the identity), ``M = R diag(exp(s))``;
- camera-space mean ``p = W mu + t``, culled unless ``near < z < far`` (then ``z`` is taken as 1 so nothing is
  infinite), ``Mc = W M``;
- ``T = J Mc`` with ``J`` the perspective Jacobian at the mean whose ``x/z``, ``y/z`` are clamped to the frustum
  widened by 30%; ``cov2d = T T^T + eps2d I``; conic = its inverse's upper triangle ``(a, b, c)``;
- colour ``max(0, 0.5 + sum_k Y_k(d) c_k)`` with ``d`` the unit direction from the camera centre to the mean.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..gaussians import SH_C0
from ..sh import SH_C1, SH_C2, SH_C3
from .lanes import _stack_empty
from .vectors import _columns_into, _sh_sums, _sh_weights

ALPHA_MIN = 1.0 / 255.0
VECTORS_REVISION = 4
"""Raised with every change to the :mod:`.vectors` intrinsics these kernels use (``_columns_into``, ``_sh_sums``,
``_sh_weights``): numba's cache checks only this file's time stamp and size (as ``kernels.LANES_REVISION``)."""

BLOCK = 1024
"""Gaussians per parallel work item (its scratch arrays are allocated once per block)."""
GROUP = 16
"""Gaussians the forward projects together, in one loop that LLVM runs on vectors (:func:`_geometry_group`; 32 were
no faster)."""

C20, C21, C22, C23, C24 = SH_C2
C30, C31, C32, C33, C34, C35, C36 = SH_C3


def activations(log_scales: np.ndarray, opacity_logits: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the scales ``exp(log_scales)`` [N, 3] and opacities ``sigmoid(logits)`` [N] in the inputs' dtype, and
    each footprint's squared Mahalanobis radius ``r2 = 2 ln(max(255 opacity, 1)) (1 + 1e-6)`` [N] in float64 (where
    ``opacity * exp(-r2 / 2) = 1/255``; the margin keeps pixels exactly on the edge for the alpha test to decide).

    numpy's exponential and logarithm work on whole arrays with the CPU's vector units; called per Gaussian in the
    compiled kernels they were a third of the projection's geometry (500k Gaussians: 0.09 -> 0.06 s in a prototype, one
    thread)."""
    with np.errstate(over="ignore"):  # exp(-logit) of a very negative logit: the opacity is 0
        opacities = 1.0 / (1.0 + np.exp(-opacity_logits))
    r2 = 2.0 * np.log(np.maximum(opacities.astype(np.float64) * 255.0, 1.0)) * (1.0 + 1e-6)
    return np.exp(log_scales), opacities, r2


@nb.njit(cache=True, nogil=True)
def _rotation(qw, qx, qy, qz):  # pragma: no cover - compiled
    """Return the rotation matrix's entries (row-major) of the normalised quaternion, the normalised (w, x, y, z)
    and the quaternion's norm (scalars only: array arguments would cost reference counting per Gaussian)."""
    norm = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    inv = 1.0 / max(norm, 1e-12)
    w, x, y, z = qw * inv, qx * inv, qy * inv, qz * inv
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y),
            w, x, y, z, norm)


@nb.njit(inline="always")
def _sh_basis(out, n_bases, x, y, z):  # pragma: no cover - compiled
    """Write the first ``n_bases`` real SH basis values at the unit direction into ``out`` [16] (the loops over the
    bases read no further): an array, so that those loops read it at a running index directly rather than a tuple
    indexed at run time (a jump table per read). Inlined into the kernels, writing only the bases in use, where a
    function returned a tuple of all 16 for the caller to store (projection 1.02-1.05x)."""
    out[0] = SH_C0
    if n_bases > 1:
        out[1], out[2], out[3] = -SH_C1 * y, SH_C1 * z, -SH_C1 * x
    xx, yy, zz = x * x, y * y, z * z
    if n_bases > 4:
        out[4], out[5] = C20 * x * y, C21 * y * z
        out[6] = C22 * (2.0 * zz - xx - yy)
        out[7], out[8] = C23 * x * z, C24 * (xx - yy)
    if n_bases > 9:
        out[9] = C30 * y * (3.0 * xx - yy)
        out[10] = C31 * x * y * z
        out[11] = C32 * y * (4.0 * zz - xx - yy)
        out[12] = C33 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
        out[13] = C34 * x * (4.0 * zz - xx - yy)
        out[14] = C35 * z * (xx - yy)
        out[15] = C36 * x * (xx - 3.0 * yy)


@nb.njit(inline="always")
def _sh_direction_grad(w, n_bases, x, y, z):  # pragma: no cover - compiled
    """The sums over the first ``n_bases`` bases of ``w[k]`` times the basis' partial derivatives along the unit
    direction's x, y and z (``w``: :func:`~.vectors._sh_weights`), base after base: only the derivatives that are not
    0 (a third of the 48 are), each by the expression and in the order of a loop over a table of all 48, whose
    products by 0 left the sums as they were (inlined; the table was 48 stores and 48 loads a Gaussian)."""
    gx = 0.0
    gy = 0.0
    gz = 0.0
    if n_bases > 1:
        gy += w[1] * -SH_C1
        gz += w[2] * SH_C1
        gx += w[3] * -SH_C1
    xx, yy, zz = x * x, y * y, z * z
    if n_bases > 4:
        gx += w[4] * (C20 * y)
        gy += w[4] * (C20 * x)
        gy += w[5] * (C21 * z)
        gz += w[5] * (C21 * y)
        gx += w[6] * (-2.0 * C22 * x)
        gy += w[6] * (-2.0 * C22 * y)
        gz += w[6] * (4.0 * C22 * z)
        gx += w[7] * (C23 * z)
        gz += w[7] * (C23 * x)
        gx += w[8] * (2.0 * C24 * x)
        gy += w[8] * (-2.0 * C24 * y)
    if n_bases > 9:
        gx += w[9] * (C30 * 6.0 * x * y)
        gy += w[9] * (C30 * (3.0 * xx - 3.0 * yy))
        gx += w[10] * (C31 * y * z)
        gy += w[10] * (C31 * x * z)
        gz += w[10] * (C31 * x * y)
        gx += w[11] * (-2.0 * C32 * x * y)
        gy += w[11] * (C32 * (4.0 * zz - xx - 3.0 * yy))
        gz += w[11] * (8.0 * C32 * y * z)
        gx += w[12] * (-6.0 * C33 * x * z)
        gy += w[12] * (-6.0 * C33 * y * z)
        gz += w[12] * (C33 * (6.0 * zz - 3.0 * xx - 3.0 * yy))
        gx += w[13] * (C34 * (4.0 * zz - 3.0 * xx - yy))
        gy += w[13] * (-2.0 * C34 * x * y)
        gz += w[13] * (8.0 * C34 * x * z)
        gx += w[14] * (2.0 * C35 * x * z)
        gy += w[14] * (-2.0 * C35 * y * z)
        gz += w[14] * (C35 * (xx - yy))
        gx += w[15] * (C36 * (3.0 * xx - 3.0 * yy))
        gy += w[15] * (-6.0 * C36 * x * y)
    return gx, gy, gz


@nb.njit(cache=True, nogil=True)
def _camera(view, intr, width, height, near, far, eps2d, tile):  # pragma: no cover - compiled
    """Return the kernels' camera tuple: the world-to-camera matrix's first three rows (12 values), fx, fy, cx, cy,
    the frustum widened by 30% that clamps the Jacobian (``x/z`` up to ``lxp``, down to ``-lxn``; ``y/z`` likewise),
    near, far, eps2d, the last pixel column and row, and the tile size (floats: the loops over Gaussians divide by
    it)."""
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    lxp = (width - cx) / fx + 0.3 * (0.5 * width / fx)
    lxn = cx / fx + 0.3 * (0.5 * width / fx)
    lyp = (height - cy) / fy + 0.3 * (0.5 * height / fy)
    lyn = cy / fy + 0.3 * (0.5 * height / fy)
    return (view[0, 0], view[0, 1], view[0, 2], view[0, 3], view[1, 0], view[1, 1], view[1, 2], view[1, 3],
            view[2, 0], view[2, 1], view[2, 2], view[2, 3], fx, fy, cx, cy, lxp, lxn, lyp, lyn, near, far, eps2d,
            width - 1.0, height - 1.0, np.float64(tile))


@nb.njit(inline="always")
def _camera_point(cam, mu0, mu1, mu2):  # pragma: no cover - compiled
    """Return the mean in camera space (p0, p1, p2), whether it is drawable (``near < z < far``), the ``z`` divided
    by (``p2``, or 1 when it is not, so nothing is infinite), ``x/z``, ``y/z`` and the two clamped to the frustum
    widened by 30% (the Jacobian's): what the forward computes and the backward recomputes (``cam``: the kernels'
    camera tuple). No branch: it runs inside the loops LLVM vectorises."""
    (v00, v01, v02, v03, v10, v11, v12, v13, v20, v21, v22, v23, fx, fy, cx, cy, lxp, lxn, lyp, lyn, near, far,
     eps2d, wf, hf, tile) = cam
    p0 = v00 * mu0 + v01 * mu1 + v02 * mu2 + v03
    p1 = v10 * mu0 + v11 * mu1 + v12 * mu2 + v13
    p2 = v20 * mu0 + v21 * mu1 + v22 * mu2 + v23
    usable = (p2 > near) & (p2 < far)
    z = p2 if usable else 1.0
    xz = p0 / z
    yz = p1 / z
    return p0, p1, p2, usable, z, xz, yz, min(max(xz, -lxn), lxp), min(max(yz, -lyn), lyp)


@nb.njit(inline="always")
def _camera_column(cam, r0, r1, r2, s):  # pragma: no cover - compiled
    """Return column ``j`` of ``W R S`` (the Gaussian's axis ``j`` in camera space) from column ``j`` of ``R``
    (``r0``, ``r1``, ``r2``) and the scale ``s``; ``W`` the rotation of the kernels' camera tuple ``cam``."""
    v00, v01, v02, _, v10, v11, v12, _, v20, v21, v22 = cam[:11]
    return ((v00 * r0 + v01 * r1 + v02 * r2) * s, (v10 * r0 + v11 * r1 + v12 * r2) * s,
            (v20 * r0 + v21 * r1 + v22 * r2) * s)


@nb.njit(inline="always")
def _screen_column(cam, a0, a1, xc, yc, r0, r1, r2, s):  # pragma: no cover - compiled
    """Return column ``j`` of ``T = J W R S`` (two rows): :func:`_camera_column` through the perspective Jacobian
    (``a0 = fx / z``, ``a1 = fy / z``, ``xc``, ``yc`` the clamped ``x/z``, ``y/z``)."""
    m0, m1, m2 = _camera_column(cam, r0, r1, r2, s)
    return a0 * (m0 - xc * m2), a1 * (m1 - yc * m2)


@nb.njit(inline="always")
def _check_rows(means, quats, scales):  # pragma: no cover - compiled
    """Raise unless the rows are as :func:`~.vectors._columns_into` reads them: 3, 4 and 3 numbers a Gaussian."""
    if means.shape[1] != 3 or quats.shape[1] != 4 or scales.shape[1] != 3:
        raise ValueError("the projection needs means [N, 3], quaternions [N, 4] and scales [N, 3]")


# rows of the per-pass buffers of :func:`project_forward`: what it reads of each Gaussian, what it computes
QW, QX, QY, QZ, S0, S1, S2, MU0, MU1, MU2, OPACITY, R2 = range(12)
DEPTH, MX, MY, CA, CB, CC, X0, X1, Y0, Y1, HX, HY, NTILES = range(13)


@nb.njit(inline="always")
def _geometry_group(inp, out, cam):  # pragma: no cover - compiled
    """Project the ``GROUP`` Gaussians of ``inp`` [12, GROUP] (rows ``QW``..``R2``) into ``out`` [13, GROUP] (rows
    ``DEPTH``..``NTILES``; ``NTILES`` 0: not drawn, the box rows then meaningless). One loop over the Gaussians with no
    branch, no call left after inlining and no array but these two (stack arrays, aliasing nothing): LLVM runs it on
    vectors of Gaussians (1.12-1.18x the whole forward's per-Gaussian loop, 500k Gaussians, one thread).
    The tile counts come from float divisions: the integer ones were a division instruction each, four per Gaussian.
    """
    fx, fy, cx, cy = cam[12:16]
    eps2d, wf, hf, tile = cam[22:26]
    for l in range(GROUP):
        r00, r01, r02, r10, r11, r12, r20, r21, r22, _, _, _, _, _ = _rotation(
            inp[QW, l], inp[QX, l], inp[QY, l], inp[QZ, l])
        p0, p1, p2, usable, z, xz, yz, xc, yc = _camera_point(cam, inp[MU0, l], inp[MU1, l], inp[MU2, l])
        out[DEPTH, l] = p2
        # T = J W R S, column by column: column j of W R S, then J's two rows
        a0 = fx / z
        a1 = fy / z
        t0, t1 = _screen_column(cam, a0, a1, xc, yc, r00, r10, r20, inp[S0, l])
        c00 = eps2d + t0 * t0
        c01 = 0.0 + t0 * t1
        c11 = eps2d + t1 * t1
        for t0, t1 in (_screen_column(cam, a0, a1, xc, yc, r01, r11, r21, inp[S1, l]),
                       _screen_column(cam, a0, a1, xc, yc, r02, r12, r22, inp[S2, l])):
            c00 += t0 * t0
            c01 += t0 * t1
            c11 += t1 * t1
        det = max(c00 * c11 - c01 * c01, 1e-30)
        out[CA, l] = c11 / det
        out[CB, l] = -c01 / det
        out[CC, l] = c00 / det
        mx = fx * xz + cx
        my = fy * yz + cy
        out[MX, l] = mx
        out[MY, l] = my
        # the footprint: where opacity * G >= 1/255
        hx = np.sqrt(inp[R2, l] * c00)
        hy = np.sqrt(inp[R2, l] * c11)
        x0 = np.ceil(mx - hx - 0.5)
        x1 = np.floor(mx + hx - 0.5)
        y0 = np.ceil(my - hy - 0.5)
        y1 = np.floor(my + hy - 0.5)
        finite = (np.abs(mx) < np.inf) & (np.abs(my) < np.inf) & (np.abs(hx) < np.inf) & (np.abs(hy) < np.inf)
        drawn = usable & (inp[OPACITY, l] >= ALPHA_MIN) & finite & (x0 <= x1) & (y0 <= y1) & (x1 >= 0.0) & \
            (y1 >= 0.0) & (x0 <= wf) & (y0 <= hf)
        bx0 = max(x0, 0.0)
        bx1 = min(x1, wf)
        by0 = max(y0, 0.0)
        by1 = min(y1, hf)
        out[X0, l] = bx0
        out[X1, l] = bx1
        out[Y0, l] = by0
        out[Y1, l] = by1
        out[HX, l] = np.ceil(hx)
        out[HY, l] = np.ceil(hy)
        tiles = (np.floor(bx1 / tile) - np.floor(bx0 / tile) + 1.0) * \
            (np.floor(by1 / tile) - np.floor(by0 / tile) + 1.0)
        out[NTILES, l] = tiles if drawn else 0.0


@nb.njit(inline="always")
def _directions(inp, center, dirs):  # pragma: no cover - compiled
    """Write the unit directions from the camera ``center`` to the ``GROUP`` means of ``inp`` (rows ``MU0``..``MU2``)
    into ``dirs`` [5, GROUP] (rows x, y, z, ``1 / |d|``, ``|d|``), in one loop LLVM runs on vectors: per Gaussian, the
    square root and division waited on each other and on the mean's load, a chain the next Gaussian's long SH loops
    could not overlap (the projection's hottest instructions)."""
    for l in range(GROUP):
        d0, d1, d2 = inp[MU0, l] - center[0], inp[MU1, l] - center[1], inp[MU2, l] - center[2]
        norm = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        inv = 1.0 / max(norm, 1e-12)
        dirs[0, l] = d0 * inv
        dirs[1, l] = d1 * inv
        dirs[2, l] = d2 * inv
        dirs[3, l] = inv
        dirs[4, l] = norm


@nb.njit(parallel=True, cache=True, nogil=True)
def project_forward(means, quats, scales, opacities, r2s, sh, n_bases, view, center, intr, width, height, near,
                    far, eps2d, tile, means2d, conics, depths, chan, bounds, half, ntiles,
                    clamped):  # pragma: no cover - compiled
    """Project every Gaussian; write means2d [N, 2], conics [N, 3], depths [N], the first four columns of ``chan``
    [N, 4 + F] (what the compositing blends: the colour, then the depth again; columns past them are left as they
    are, for the features; written here, where a numpy concatenation after the kernel was 0.5 ms at 100k Gaussians)
    with as colour, when ``n_bases`` > 0, the SH colours of ``sh`` [N, K, 3] of the drawn Gaussians, clamped at 0, 0
    for the others, whose colour nothing reads, and otherwise ``sh[:, 0]`` (the colours themselves, [N, 1, 3]), and
    the footprints: bounds [N, 4] (inclusive pixel box), half [N, 2], ntiles [N] (0: not drawn; the bounds and half
    of those are left as the caller filled them). With SH,
    ``clamped`` [N] gets bit ``c`` set where channel ``c``'s value was not >= 0 (where the clamp passes no gradient:
    the backward reads it instead of evaluating the colours again).

    ``scales`` [N, 3], ``opacities`` [N] and ``r2s`` [N] are :func:`activations` of the log-scales and logits;
    ``view`` is the 4x4 world-to-camera matrix, ``center`` the camera centre [3], ``intr`` (fx, fy, cx, cy).
    ``GROUP`` Gaussians at a time are copied into a stack buffer, projected together (:func:`_geometry_group`) and
    written out; each drawn one's colour then reads its SH coefficients.
    """
    n = means.shape[0]
    _check_rows(means, quats, scales)
    cam = _camera(view, intr, width, height, near, far, eps2d, tile)
    for blk in nb.prange((n + BLOCK - 1) // BLOCK):
        basis = nb.carray(_stack_empty(16, view), (16,))
        inp = nb.carray(_stack_empty(192, view), (12, GROUP))  # sizes: integer literals, 12 and 13 rows of GROUP
        out = nb.carray(_stack_empty(208, view), (13, GROUP))
        dirs = nb.carray(_stack_empty(80, view), (5, GROUP))  # the unit directions from the camera, 1 / |d|, |d|
        inp[:] = 0.0  # the lanes past the last Gaussian compute on zeros, and are not written out
        end = min(n, (blk + 1) * BLOCK)
        for first in range(blk * BLOCK, end, GROUP):
            m = min(GROUP, end - first)
            if m == GROUP:  # the rows read as vectors and parted by shuffles (a loop over them became gathers)
                _columns_into(inp, QW, quats, first, 4)
                _columns_into(inp, S0, scales, first, 3)
                _columns_into(inp, MU0, means, first, 3)
                for l in range(GROUP):
                    inp[OPACITY, l], inp[R2, l] = np.float64(opacities[first + l]), r2s[first + l]
            else:
                for l in range(m):
                    i = first + l
                    inp[QW, l], inp[QX, l] = np.float64(quats[i, 0]), np.float64(quats[i, 1])
                    inp[QY, l], inp[QZ, l] = np.float64(quats[i, 2]), np.float64(quats[i, 3])
                    inp[S0, l], inp[S1, l], inp[S2, l] = (np.float64(scales[i, 0]), np.float64(scales[i, 1]),
                                                          np.float64(scales[i, 2]))
                    inp[MU0, l], inp[MU1, l], inp[MU2, l] = (np.float64(means[i, 0]), np.float64(means[i, 1]),
                                                             np.float64(means[i, 2]))
                    inp[OPACITY, l], inp[R2, l] = np.float64(opacities[i]), r2s[i]
            _geometry_group(inp, out, cam)
            if n_bases > 0:
                _directions(inp, center, dirs)
            for l in range(m):
                i = first + l
                depths[i] = out[DEPTH, l]
                conics[i, 0], conics[i, 1], conics[i, 2] = out[CA, l], out[CB, l], out[CC, l]
                means2d[i, 0], means2d[i, 1] = out[MX, l], out[MY, l]
                chan[i, 3] = out[DEPTH, l]
                ntiles[i] = int(out[NTILES, l])
                if ntiles[i] > 0:
                    bounds[i, 0], bounds[i, 1] = int(out[X0, l]), int(out[X1, l])
                    bounds[i, 2], bounds[i, 3] = int(out[Y0, l]), int(out[Y1, l])
                    half[i, 0], half[i, 1] = int(out[HX, l]), int(out[HY, l])
                if n_bases == 0:
                    chan[i, 0], chan[i, 1], chan[i, 2] = sh[i, 0, 0], sh[i, 0, 1], sh[i, 0, 2]
                    continue
                v0 = v1 = v2 = 0.0
                if ntiles[i] > 0:
                    _sh_basis(basis, n_bases, dirs[0, l], dirs[1, l], dirs[2, l])
                    # 0.5 + the bases' products, base after base (the channels as one vector's lanes)
                    if n_bases == 16:
                        v0, v1, v2 = _sh_sums(basis, sh, i, 16, 0.5)
                    elif n_bases == 9:
                        v0, v1, v2 = _sh_sums(basis, sh, i, 9, 0.5)
                    elif n_bases == 4:
                        v0, v1, v2 = _sh_sums(basis, sh, i, 4, 0.5)
                    else:
                        v0, v1, v2 = _sh_sums(basis, sh, i, 1, 0.5)
                chan[i, 0] = max(v0, 0.0)
                chan[i, 1] = max(v1, 0.0)
                chan[i, 2] = max(v2, 0.0)
                clamped[i] = (0 if v0 >= 0.0 else 1) | (0 if v1 >= 0.0 else 2) | (0 if v2 >= 0.0 else 4)


# rows of the per-pass buffers of :func:`project_backward` (its inputs beyond the forward's: the outputs' gradients,
# and the means' gradient from the colours), and what it computes
GMX, GMY, GA, GB, GC, GOPACITY, GDEPTH, GSH0, GSH1, GSH2 = range(12, 22)
GMU0, GMU1, GMU2, GS0, GS1, GS2, GQW, GQX, GQY, GQZ, GLOGIT = range(11)


@nb.njit(inline="always")
def _quaternion_grad(w, x, y, z_, qnorm, gR00, gR01, gR02, gR10, gR11, gR12, gR20, gR21,
                     gR22):  # pragma: no cover - compiled
    """The gradient of the raw quaternion from that of its rotation matrix ``gR`` (row-major): through R of the
    normalised quaternion (w, x, y, z), then the normalisation q / max(|q|, 1e-12)."""
    gw = 2.0 * (-z_ * gR01 + y * gR02 + z_ * gR10 - x * gR12 - y * gR20 + x * gR21)
    gx = 2.0 * (y * gR01 + z_ * gR02 + y * gR10 - 2.0 * x * gR11 - w * gR12 + z_ * gR20 + w * gR21
                - 2.0 * x * gR22)
    gy = 2.0 * (-2.0 * y * gR00 + x * gR01 + w * gR02 + x * gR10 + z_ * gR12 - w * gR20 + z_ * gR21
                - 2.0 * y * gR22)
    gz = 2.0 * (-2.0 * z_ * gR00 - w * gR01 + x * gR02 + w * gR10 - 2.0 * z_ * gR11 + y * gR12 + x * gR20
                + y * gR21)
    dot = gw * w + gx * x + gy * y + gz * z_
    unit = qnorm > 1e-12
    gw = gw - dot * w if unit else gw
    gx = gx - dot * x if unit else gx
    gy = gy - dot * y if unit else gy
    gz = gz - dot * z_ if unit else gz
    inv_q = 1.0 / max(qnorm, 1e-12)
    return gw * inv_q, gx * inv_q, gy * inv_q, gz * inv_q


@nb.njit(inline="always")
def _backward_group(inp, out, cam):  # pragma: no cover - compiled
    """The projection's gradients of the ``GROUP`` Gaussians of ``inp`` [22, GROUP] (rows ``QW``..``R2`` as the
    forward's, then ``GMX``..``GSH2``) into ``out`` [11, GROUP] (rows ``GMU0``..``GLOGIT``): the forward recomputed,
    then its derivatives in reverse, one branch-free loop over the Gaussians that LLVM runs on vectors, as
    :func:`_geometry_group`. Every expression is the one the per-Gaussian loop had, in the same order (the gradients
    are bit-identical)."""
    (v00, v01, v02, v03, v10, v11, v12, v13, v20, v21, v22, v23, fx, fy, cx, cy, lxp, lxn, lyp, lyn, near, far,
     eps2d, wf, hf, tile) = cam
    for l in range(GROUP):
        r00, r01, r02, r10, r11, r12, r20, r21, r22, w, x, y, z_, qnorm = _rotation(
            inp[QW, l], inp[QX, l], inp[QY, l], inp[QZ, l])
        s0, s1, s2 = inp[S0, l], inp[S1, l], inp[S2, l]
        p0, p1, p2, usable, z, xz, yz, xc, yc = _camera_point(cam, inp[MU0, l], inp[MU1, l], inp[MU2, l])
        # Mc = W R S (columns j), T = J Mc (rows 0 and 1)
        m00, m10, m20 = _camera_column(cam, r00, r10, r20, s0)
        m01, m11, m21 = _camera_column(cam, r01, r11, r21, s1)
        m02, m12, m22 = _camera_column(cam, r02, r12, r22, s2)
        t00, t01, t02 = fx / z * (m00 - xc * m20), fx / z * (m01 - xc * m21), fx / z * (m02 - xc * m22)
        t10, t11, t12 = fy / z * (m10 - yc * m20), fy / z * (m11 - yc * m21), fy / z * (m12 - yc * m22)
        c00 = eps2d + t00 * t00 + t01 * t01 + t02 * t02
        c01 = t00 * t10 + t01 * t11 + t02 * t12
        c11 = eps2d + t10 * t10 + t11 * t11 + t12 * t12
        raw_det = c00 * c11 - c01 * c01
        det = max(raw_det, 1e-30)
        # conic (a, b, c) = (c11, -c01, c00) / det
        ga, gb, gc = inp[GA, l], inp[GB, l], inp[GC, l]
        g_c00 = gc / det
        g_c11 = ga / det
        g_c01 = -gb / det
        g_det = -(ga * c11 - gb * c01 + gc * c00) / (det * det)
        free = raw_det > 1e-30  # the determinant not clamped
        g_c00 = g_c00 + g_det * c11 if free else g_c00
        g_c11 = g_c11 + g_det * c00 if free else g_c11
        g_c01 = g_c01 - 2.0 * g_det * c01 if free else g_c01
        # cov2d = T T^T + eps; T0 = fx/z (Mc0 - xc Mc2), T1 = fy/z (Mc1 - yc Mc2)
        u00, u01, u02 = (2.0 * g_c00 * t00 + g_c01 * t10, 2.0 * g_c00 * t01 + g_c01 * t11,
                         2.0 * g_c00 * t02 + g_c01 * t12)
        u10, u11, u12 = (2.0 * g_c11 * t10 + g_c01 * t00, 2.0 * g_c11 * t11 + g_c01 * t01,
                         2.0 * g_c11 * t12 + g_c01 * t02)
        n00, n01, n02 = fx / z * u00, fx / z * u01, fx / z * u02
        n10, n11, n12 = fy / z * u10, fy / z * u11, fy / z * u12
        n20 = -(fx / z * xc * u00 + fy / z * yc * u10)
        n21 = -(fx / z * xc * u01 + fy / z * yc * u11)
        n22 = -(fx / z * xc * u02 + fy / z * yc * u12)
        g_xc = 0.0 - fx / z * m20 * u00 - fx / z * m21 * u01 - fx / z * m22 * u02
        g_yc = 0.0 - fy / z * m20 * u10 - fy / z * m21 * u11 - fy / z * m22 * u12
        g_z = 0.0 - (u00 * t00 + u10 * t10) / z - (u01 * t01 + u11 * t11) / z - (u02 * t02 + u12 * t12) / z
        # means2d = (fx xz + cx, fy yz + cy); the clamps pass the gradient inside the frustum
        g_xz = fx * inp[GMX, l] + (g_xc if (-lxn < xz) & (xz < lxp) else 0.0)
        g_yz = fy * inp[GMY, l] + (g_yc if (-lyn < yz) & (yz < lyp) else 0.0)
        g_p0 = g_xz / z
        g_p1 = g_yz / z
        g_z -= (g_xz * p0 + g_yz * p1) / (z * z)
        g_p2 = inp[GDEPTH, l] + (g_z if usable else 0.0)
        out[GMU0, l] = inp[GSH0, l] + v00 * g_p0 + v10 * g_p1 + v20 * g_p2
        out[GMU1, l] = inp[GSH1, l] + v01 * g_p0 + v11 * g_p1 + v21 * g_p2
        out[GMU2, l] = inp[GSH2, l] + v02 * g_p0 + v12 * g_p1 + v22 * g_p2
        # Mc = W R S: gR = W^T gMc S, g_s[j] = (W^T gMc)[:, j] . R[:, j]
        w00, w10, w20 = v00 * n00 + v10 * n10 + v20 * n20, v01 * n00 + v11 * n10 + v21 * n20, \
            v02 * n00 + v12 * n10 + v22 * n20
        w01, w11, w21 = v00 * n01 + v10 * n11 + v20 * n21, v01 * n01 + v11 * n11 + v21 * n21, \
            v02 * n01 + v12 * n11 + v22 * n21
        w02, w12, w22 = v00 * n02 + v10 * n12 + v20 * n22, v01 * n02 + v11 * n12 + v21 * n22, \
            v02 * n02 + v12 * n12 + v22 * n22
        out[GS0, l] = (0.0 + w00 * r00 + w10 * r10 + w20 * r20) * s0
        out[GS1, l] = (0.0 + w01 * r01 + w11 * r11 + w21 * r21) * s1
        out[GS2, l] = (0.0 + w02 * r02 + w12 * r12 + w22 * r22) * s2
        gR00, gR10, gR20 = w00 * s0, w10 * s0, w20 * s0
        gR01, gR11, gR21 = w01 * s1, w11 * s1, w21 * s1
        gR02, gR12, gR22 = w02 * s2, w12 * s2, w22 * s2
        out[GQW, l], out[GQX, l], out[GQY, l], out[GQZ, l] = _quaternion_grad(
            w, x, y, z_, qnorm, gR00, gR01, gR02, gR10, gR11, gR12, gR20, gR21, gR22)
        o = inp[OPACITY, l]
        out[GLOGIT, l] = inp[GOPACITY, l] * o * (1.0 - o)


@nb.njit(parallel=True, cache=True, nogil=True)
def project_backward(means, quats, scales, opacities, sh, n_bases, view, center, intr, width, height, near,
                     far, eps2d, ntiles, clamped, g_means2d, g_conics, g_opacities, g_rgb, g_depths, g_means, g_quats,
                     g_log_scales, g_logits, g_sh, geometry):  # pragma: no cover - compiled
    """Write the gradients of the inputs of :func:`project_forward` (and of the log-scales and logits behind its
    ``scales`` and ``opacities``) from those of its outputs.

    ``g_rgb`` [N, 3] is used when ``n_bases`` > 0 (then ``g_sh`` [N, K, 3] is written and the direction's gradient
    reaches the means, except through the channels the forward ``clamped``); ``geometry`` False skips the projection's
    gradients (only colours are trained). Gaussians the forward did not draw (``ntiles`` 0) have no gradient from the
    image: their rows of every output are zeroed here (the caller's arrays need not be: a serial memset of them was
    a tenth of this kernel's time); a drawn Gaussian's rows of ``g_quats``, ``g_log_scales`` and ``g_logits`` without
    ``geometry``, and of ``g_sh`` without SH, are left as the caller filled them. Each drawn Gaussian's colour gradients
    are worked out in turn, then ``GROUP`` Gaussians' projection gradients together (:func:`_backward_group`).
    """
    n = means.shape[0]
    _check_rows(means, quats, scales)
    cam = _camera(view, intr, width, height, near, far, eps2d, 1)  # (the tile size: the forward's alone)
    for blk in nb.prange((n + BLOCK - 1) // BLOCK):
        basis = nb.carray(_stack_empty(16, view), (16,))
        inp = nb.carray(_stack_empty(352, view), (22, GROUP))  # sizes: integer literals, 22 and 11 rows of GROUP
        out = nb.carray(_stack_empty(176, view), (11, GROUP))
        dirs = nb.carray(_stack_empty(80, view), (5, GROUP))  # as the forward's
        inp[:] = 1.0  # lanes of Gaussians not drawn compute on whatever their rows hold, and are not written out
        end = min(n, (blk + 1) * BLOCK)
        for first in range(blk * BLOCK, end, GROUP):
            m = min(GROUP, end - first)
            if m == GROUP:  # as the forward's: no gathers
                _columns_into(inp, MU0, means, first, 3)
                if geometry:
                    _columns_into(inp, QW, quats, first, 4)
                    _columns_into(inp, S0, scales, first, 3)
            else:
                for l in range(m):
                    i = first + l
                    inp[MU0, l], inp[MU1, l], inp[MU2, l] = (np.float64(means[i, 0]), np.float64(means[i, 1]),
                                                             np.float64(means[i, 2]))
            if n_bases > 0:
                _directions(inp, center, dirs)
            for l in range(m):
                i = first + l
                if ntiles[i] == 0:  # no gradient from the image
                    g_means[i, :] = 0.0
                    g_quats[i, :] = 0.0
                    g_log_scales[i, :] = 0.0
                    g_logits[i] = 0.0
                    g_sh[i, :, :] = 0.0
                    continue
                gm0 = 0.0
                gm1 = 0.0
                gm2 = 0.0
                if n_bases > 0:
                    ux, uy, uz, inv, norm = dirs[0, l], dirs[1, l], dirs[2, l], dirs[3, l], dirs[4, l]
                    _sh_basis(basis, n_bases, ux, uy, uz)
                    cut = clamped[i]  # the channels whose value the forward clamped at 0 pass no gradient
                    g0 = np.float64(g_rgb[i, 0]) if (cut & 1) == 0 else 0.0
                    g1 = np.float64(g_rgb[i, 1]) if (cut & 2) == 0 else 0.0
                    g2 = np.float64(g_rgb[i, 2]) if (cut & 4) == 0 else 0.0
                    # dL/d(coefficient) (on vectors of the bases) and, through the basis, dL/d(direction)
                    if n_bases == 16:
                        wts = _sh_weights(basis, sh, g_sh, i, 16, g0, g1, g2)
                    elif n_bases == 9:
                        wts = _sh_weights(basis, sh, g_sh, i, 9, g0, g1, g2)
                    elif n_bases == 4:
                        wts = _sh_weights(basis, sh, g_sh, i, 4, g0, g1, g2)
                    else:
                        wts = _sh_weights(basis, sh, g_sh, i, 1, g0, g1, g2)
                    gux, guy, guz = _sh_direction_grad(wts, n_bases, ux, uy, uz)
                    g_sh[i, n_bases:, :] = 0.0  # coefficients past the degree in use
                    if norm > 1e-12:  # d(d / |d|) = (I - u u^T) / |d|
                        dot = gux * ux + guy * uy + guz * uz
                        gux -= dot * ux
                        guy -= dot * uy
                        guz -= dot * uz
                    gm0 += gux * inv
                    gm1 += guy * inv
                    gm2 += guz * inv
                if not geometry:
                    g_means[i, 0] = gm0
                    g_means[i, 1] = gm1
                    g_means[i, 2] = gm2
                    continue
                if m < GROUP:
                    inp[QW, l], inp[QX, l] = np.float64(quats[i, 0]), np.float64(quats[i, 1])
                    inp[QY, l], inp[QZ, l] = np.float64(quats[i, 2]), np.float64(quats[i, 3])
                    inp[S0, l], inp[S1, l], inp[S2, l] = (np.float64(scales[i, 0]), np.float64(scales[i, 1]),
                                                          np.float64(scales[i, 2]))
                inp[OPACITY, l] = np.float64(opacities[i])
                inp[GMX, l], inp[GMY, l] = np.float64(g_means2d[i, 0]), np.float64(g_means2d[i, 1])
                inp[GA, l], inp[GB, l] = np.float64(g_conics[i, 0]), np.float64(g_conics[i, 1])
                inp[GC, l] = np.float64(g_conics[i, 2])
                inp[GOPACITY, l], inp[GDEPTH, l] = np.float64(g_opacities[i]), np.float64(g_depths[i])
                inp[GSH0, l], inp[GSH1, l], inp[GSH2, l] = gm0, gm1, gm2
            if not geometry:
                continue
            _backward_group(inp, out, cam)
            for l in range(m):
                i = first + l
                if ntiles[i] == 0:
                    continue
                g_means[i, 0], g_means[i, 1], g_means[i, 2] = out[GMU0, l], out[GMU1, l], out[GMU2, l]
                g_log_scales[i, 0], g_log_scales[i, 1], g_log_scales[i, 2] = out[GS0, l], out[GS1, l], out[GS2, l]
                g_quats[i, 0], g_quats[i, 1] = out[GQW, l], out[GQX, l]
                g_quats[i, 2], g_quats[i, 3] = out[GQY, l], out[GQZ, l]
                g_logits[i] = out[GLOGIT, l]
