"""Brox optical flow (Brox, Bruhn, Papenberg and Weickert, ECCV 2004), written in torch so that it
runs batched on the CPU and, unchanged, on a GPU.

Energy: one robust (Charbonnier, ``psi(s2) = sqrt(s2 + 1e-6)``) penalty over brightness
constancy plus ``gamma`` times gradient constancy (the paper's data term, as OpenCV's CUDA class
has it: one penalty, so that a gradient mismatch cannot stiffen the system on its own), and
``alpha`` times a robust smoothness term on the flow's gradient. Minimised coarse to fine (a
pyramid scaled by ``scale_factor`` per level): at each level the second frame is warped by the
current flow, and ``inner_iterations`` lagged
fixed-point steps linearise the data term around it, each solved for the flow increment by
``solver_iterations`` red-black SOR sweeps. Defaults are OpenCV's CUDA ``BroxOpticalFlow``'s
(alpha 0.197, gamma 50, scale 0.8, inner 5, solver 10), the settings action-recognition
pipelines computed their Brox flow with; intensities are scaled to 0..1 first, as there.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from edr.checks.config import OpenFraction, PositiveFloat, PositiveInt, check_arguments
from edr.representations.base import FlowRepresentation, check_clip, to_gray

EPS2 = 1e-6  # Charbonnier's epsilon squared (eps = 0.001)
SOR_OMEGA = 1.99  # over-relaxation of the red-black sweeps (OpenCV's CUDA class uses 1.99)


def _psi_prime(s2: torch.Tensor) -> torch.Tensor:
    """Derivative of the Charbonnier penalty psi(s2) = sqrt(s2 + eps2), with respect to s2 (x2)."""
    return 0.5 / torch.sqrt(s2 + EPS2)


def _dx(x: torch.Tensor) -> torch.Tensor:
    """Five-point derivative along width, (-1, 8, 0, -8, 1) / 12, borders replicated."""
    p = F.pad(x, (2, 2, 0, 0), mode="replicate")
    return (p[..., :-4] - 8 * p[..., 1:-3] + 8 * p[..., 3:-1] - p[..., 4:]) / 12


def _dy(x: torch.Tensor) -> torch.Tensor:
    p = F.pad(x, (0, 0, 2, 2), mode="replicate")
    return (p[..., :-4, :] - 8 * p[..., 1:-3, :] + 8 * p[..., 3:-1, :] - p[..., 4:, :]) / 12


def _warp(image: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``image`` (N, 1, H, W) sampled at (x + u, y + v), bicubic (as the IPOL Brox code and
    OpenCV's TV-L1 warp: bilinear biased a 2.3 px shift by +0.05 px), borders replicated."""
    h, w = image.shape[-2:]
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=image.dtype, device=image.device),
        torch.arange(w, dtype=image.dtype, device=image.device),
        indexing="ij",
    )
    gx = 2 * (xs + u[:, 0]) / max(w - 1, 1) - 1
    gy = 2 * (ys + v[:, 0]) / max(h - 1, 1) - 1
    grid = torch.stack((gx, gy), dim=-1)  # (N, H, W, 2)
    return F.grid_sample(image, grid, mode="bicubic", padding_mode="border", align_corners=True)


def _resize(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    return F.interpolate(x, size=size, mode="bilinear", align_corners=True)


def _smooth(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """Gaussian blur of (N, 1, H, W) before downsampling."""
    radius = max(1, math.ceil(2 * sigma))
    t = torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device)
    kernel = torch.exp(-(t**2) / (2 * sigma**2))
    kernel = kernel / kernel.sum()
    x = F.conv2d(F.pad(x, (radius, radius, 0, 0), mode="replicate"), kernel.view(1, 1, 1, -1))
    return F.conv2d(F.pad(x, (0, 0, radius, radius), mode="replicate"), kernel.view(1, 1, -1, 1))


def _edge_weights(u: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Smoothness diffusivities psi'(|grad u|^2 + |grad v|^2) on the horizontal edges (between x and
    x+1) and vertical edges (between y and y+1), averaged from the two pixels; 0 past the border."""
    s2 = _dx(u) ** 2 + _dy(u) ** 2 + _dx(v) ** 2 + _dy(v) ** 2
    psi = _psi_prime(s2)
    right = F.pad(0.5 * (psi[..., :, 1:] + psi[..., :, :-1]), (0, 1))  # (N, 1, H, W), last col 0
    down = F.pad(0.5 * (psi[..., 1:, :] + psi[..., :-1, :]), (0, 0, 0, 1))
    return right, down


def _neighbour_sum(
    field: torch.Tensor, right: torch.Tensor, down: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """(sum over the 4 neighbours of weight * field, sum of the weights); weights on edges."""
    left = F.pad(right[..., :, :-1], (1, 0))
    up = F.pad(down[..., :-1, :], (0, 0, 1, 0))
    f_right = F.pad(field[..., :, 1:], (0, 1))
    f_left = F.pad(field[..., :, :-1], (1, 0))
    f_down = F.pad(field[..., 1:, :], (0, 0, 0, 1))
    f_up = F.pad(field[..., :-1, :], (0, 0, 1, 0))
    weighted = right * f_right + left * f_left + down * f_down + up * f_up
    return weighted, right + left + down + up


def _increment(
    i1: torch.Tensor,
    i2: torch.Tensor,
    u: torch.Tensor,
    v: torch.Tensor,
    red: torch.Tensor,
    alpha: float,
    gamma: float,
    inner_iterations: int,
    solver_iterations: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The flow increment (du, dv) at one warp of one level: ``inner_iterations`` lagged
    fixed-point steps, each ``solver_iterations`` red-black SOR sweeps."""
    i1x, i1y = _dx(i1), _dy(i1)
    warped = _warp(i2, u, v)
    wx, wy = _dx(warped), _dy(warped)
    # Derivatives averaged over the two frames, the temporal ones between them.
    ix, iy, iz = 0.5 * (i1x + wx), 0.5 * (i1y + wy), warped - i1
    ixx, ixy, iyy = _dx(ix), _dy(ix), _dy(iy)
    ixz, iyz = wx - i1x, wy - i1y
    du, dv = torch.zeros_like(u), torch.zeros_like(v)
    for _ in range(inner_iterations):
        # Lagged nonlinearities at the current increment: one robust penalty over brightness
        # and gamma times gradient constancy (Brox et al.'s data term).
        psi_data = _psi_prime(
            (iz + ix * du + iy * dv) ** 2
            + gamma * ((ixz + ixx * du + ixy * dv) ** 2 + (iyz + ixy * du + iyy * dv) ** 2)
        )
        psi_grad = gamma * psi_data
        right, down = _edge_weights(u + du, v + dv)
        right, down = alpha * right, alpha * down
        a11 = psi_data * ix * ix + psi_grad * (ixx * ixx + ixy * ixy)
        a12 = psi_data * ix * iy + psi_grad * (ixx * ixy + ixy * iyy)
        a22 = psi_data * iy * iy + psi_grad * (ixy * ixy + iyy * iyy)
        b1 = -(psi_data * ix * iz + psi_grad * (ixx * ixz + ixy * iyz))
        b2 = -(psi_data * iy * iz + psi_grad * (ixy * ixz + iyy * iyz))
        # The smoothness of u itself (not only of du) enters the right-hand side.
        su, weights = _neighbour_sum(u, right, down)
        sv, _ = _neighbour_sum(v, right, down)
        b1 = b1 + su - weights * u
        b2 = b2 + sv - weights * v
        for _ in range(solver_iterations):
            for mask in (red, ~red):
                nu, _ = _neighbour_sum(du, right, down)
                nv, _ = _neighbour_sum(dv, right, down)
                new_du = (b1 + nu - a12 * dv) / (a11 + weights + 1e-9)
                du = torch.where(mask, du + SOR_OMEGA * (new_du - du), du)
                new_dv = (b2 + nv - a12 * du) / (a22 + weights + 1e-9)
                dv = torch.where(mask, dv + SOR_OMEGA * (new_dv - dv), dv)
    return du, dv


def brox_flow(
    first: torch.Tensor,
    second: torch.Tensor,
    alpha: float = 0.197,
    gamma: float = 50.0,
    scale_factor: float = 0.8,
    inner_iterations: int = 5,
    solver_iterations: int = 10,
    min_size: int = 16,
) -> torch.Tensor:
    """Flow (N, 2, H, W) that carries ``first`` (N, 1, H, W) onto ``second``: second(x + w) ~
    first(x). Intensities 0..1. One warp per pyramid level, as OpenCV's CUDA class (more warps
    per level did not lower the error on the ground-truth pairs of ``edr.studies.flows``)."""
    n, _, h, w = first.shape
    levels = [(h, w)]
    while min(levels[-1]) * scale_factor >= min_size:
        lh, lw = levels[-1]
        levels.append((max(1, round(lh * scale_factor)), max(1, round(lw * scale_factor))))
    sigma = 1.0 / math.sqrt(2 * scale_factor)  # blur before each downsampling
    pyramid = [(first, second)]
    for size in levels[1:]:
        a, b = pyramid[-1]
        pyramid.append((_resize(_smooth(a, sigma), size), _resize(_smooth(b, sigma), size)))
    # A red-black checkerboard, so that each half-sweep updates pixels whose neighbours are fixed.
    u = v = None
    for (lh, lw), (i1, i2) in zip(reversed(levels), reversed(pyramid), strict=True):
        if u is None:
            u = torch.zeros((n, 1, lh, lw), dtype=first.dtype, device=first.device)
            v = torch.zeros_like(u)
        else:
            u = _resize(u, (lh, lw)) * (lw / u.shape[-1])
            v = _resize(v, (lh, lw)) * (lh / v.shape[-2])
        yy, xx = torch.meshgrid(torch.arange(lh), torch.arange(lw), indexing="ij")
        red = ((yy + xx) % 2 == 0).to(first.device).view(1, 1, lh, lw)
        du, dv = _increment(i1, i2, u, v, red, alpha, gamma, inner_iterations, solver_iterations)
        u, v = u + du, v + dv
    return torch.cat((u, v), dim=1)


MAX_INTENSITY = 1e6  # far above any video; float32 squares of image gradients stay finite


class BroxFlow(FlowRepresentation):
    """Brox et al. (2004) flow: (B, T, C, H, W) -> (B, T-1, 2, H, W), (dx, dy), every pair of
    consecutive frames in one batch, on the clip's device. See :func:`brox_flow`."""

    def __init__(
        self,
        alpha: PositiveFloat = 0.197,
        gamma: PositiveFloat = 50.0,
        scale_factor: OpenFraction = 0.8,
        inner_iterations: PositiveInt = 5,
        solver_iterations: PositiveInt = 10,
        min_size: PositiveInt = 16,
    ) -> None:
        super().__init__()
        check_arguments(self, locals())
        self.settings = {
            "alpha": alpha,
            "gamma": gamma,
            "scale_factor": scale_factor,
            "inner_iterations": inner_iterations,
            "solver_iterations": solver_iterations,
            "min_size": min_size,
        }

    @torch.no_grad()
    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        check_clip(frames, min_frames=2, name="frames")
        if frames.is_floating_point() and float(frames.max()) > MAX_INTENSITY:
            raise ValueError(
                f"frames reach {float(frames.max()):.3g}: Brox expects video intensities, 0..255 "
                f"(at most {MAX_INTENSITY:g}; its squared gradients overflow beyond)"
            )
        gray = to_gray(frames, channel_dim=2).float() / 255.0  # (B, T, 1, H, W), 0..1
        b, t, _, h, w = gray.shape
        first = gray[:, :-1].reshape(-1, 1, h, w)
        second = gray[:, 1:].reshape(-1, 1, h, w)
        flow = brox_flow(first, second, **self.settings)  # (B*(T-1), 2, H, W)
        return flow.view(b, t - 1, 2, h, w)
