"""A differentiable Gaussian rasterizer in plain PyTorch, for the rendered losses (ARCHITECTURE.md §5).

Dense rather than tiled: every Gaussian against every pixel of a small render (e.g. 32×24), which
is what makes it fit on a CPU at training resolution. The maths is the node's rasterizer's: EWA
projection Σ' = J W Σ Wᵀ Jᵀ + 0.3 px low-pass, near-plane culling, front-to-back compositing in depth
order with alpha = min(0.99, o·exp(−½ dᵀ Σ'⁻¹ d)) and contributions below 1/255 dropped.
"""

import torch


def quaternion_matrix(q):
    """[N,4] xyzw (normalised here) -> [N,3,3]."""
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    x, y, z, w = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)


def render(means, rotations, scales, opacities, features, k, world_from_camera, height, width, near=0.05):
    """Render `features` [N,C] of Gaussians (world `means` [N,3], world `rotations` [N,3,3], `scales`
    [N,3] std devs in metres, `opacities` [N]) into a camera with intrinsics `k` [3,3] (for this
    height × width) and pose `world_from_camera` [4,4]. Returns (features [H,W,C], alpha [H,W])."""
    rotation = world_from_camera[:3, :3]
    translation = world_from_camera[:3, 3]
    p = (means - translation) @ rotation  # camera frame: Rᵀ (m − t)
    z = p[:, 2]
    keep = z > near
    p, z = p[keep], z[keep]
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    u = fx * p[:, 0] / z + cx
    v = fy * p[:, 1] / z + cy
    # Covariance in the camera frame, then the EWA Jacobian.
    r_cam = rotation.T @ rotations[keep]
    s = scales[keep]
    cov = r_cam @ torch.diag_embed(s * s) @ r_cam.transpose(1, 2)
    zero = torch.zeros_like(z)
    jacobian = torch.stack([
        torch.stack([fx / z, zero, -fx * p[:, 0] / (z * z)], dim=-1),
        torch.stack([zero, fy / z, -fy * p[:, 1] / (z * z)], dim=-1),
    ], dim=1)  # [N,2,3]
    cov2 = jacobian @ cov @ jacobian.transpose(1, 2) + 0.3 * torch.eye(2)
    a, b, c = cov2[:, 0, 0], cov2[:, 0, 1], cov2[:, 1, 1]
    det = (a * c - b * b).clamp_min(1e-12)
    inv_a, inv_b, inv_c = c / det, -b / det, a / det
    order = torch.argsort(z)
    u, v, inv_a, inv_b, inv_c = u[order], v[order], inv_a[order], inv_b[order], inv_c[order]
    o = opacities[keep][order]
    f = features[keep][order]
    ys, xs = torch.meshgrid(torch.arange(height, dtype=means.dtype), torch.arange(width, dtype=means.dtype),
                            indexing='ij')
    dx = xs.reshape(-1, 1) - u[None]
    dy = ys.reshape(-1, 1) - v[None]
    power = -0.5 * (inv_a[None] * dx * dx + 2 * inv_b[None] * dx * dy + inv_c[None] * dy * dy)
    alpha = (o[None] * torch.exp(power.clamp(max=0.0))).clamp(max=0.99)
    alpha = alpha * (alpha >= 1.0 / 255.0)
    # Exclusive cumulative transmittance along depth order.
    transmittance = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1 - alpha[:, :-1]], dim=1), dim=1)
    weights = alpha * transmittance
    out = weights @ f
    return out.reshape(height, width, -1), weights.sum(dim=1).reshape(height, width)
