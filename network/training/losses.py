"""The paper's losses: supervised cross entropy, LSGAN, short- and long-range consistency.

Shapes: logits ``(B, T, R, 3, D, D)`` per view, targets ``(B, T, R, D, D)`` int64.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from layouts import BOX, LayoutSpec


def supervised_loss(
    logits: torch.Tensor,
    target: torch.Tensor,
    class_weights: torch.Tensor | None = None,
    dice_weight: float = 0.0,
    valid: torch.Tensor | None = None,
    column_weights: torch.Tensor | None = None,
) -> torch.Tensor:
    """Per-pixel cross entropy over every shelf slot (optionally class-weighted) + soft Dice on boxes.

    ``valid`` ``(B, T, R)`` keeps only the slots that exist (a slot without a shelf is background
    by construction and teaches nothing). ``column_weights`` ``(B, T, R, D)`` weights each layout
    column's cells (all ones gives the unweighted loss). The Dice term (weight ``dice_weight``) is
    computed per slot, so a slot with few box pixels still pulls as hard as a crowded one.
    """
    c = logits.shape[-3]
    flat = logits.reshape(-1, c, *logits.shape[-2:])
    tgt = target.reshape(-1, *target.shape[-2:])
    cols = None if column_weights is None else column_weights.reshape(-1, 1, column_weights.shape[-1])
    if valid is not None:
        keep = valid.reshape(-1)
        if not bool(keep.any()):
            return logits.sum() * 0.0
        flat, tgt = flat[keep], tgt[keep]
        cols = None if cols is None else cols[keep]
    if cols is None:
        loss = F.cross_entropy(flat, tgt, weight=class_weights)
    else:
        per = F.cross_entropy(flat, tgt, weight=class_weights, reduction="none")
        w = cols.expand_as(per) if class_weights is None else cols * class_weights[tgt]
        loss = (per * cols).sum() / w.sum().clamp_min(1e-12)
    if dice_weight > 0:
        p = flat.softmax(1)[:, BOX]
        g = (tgt == BOX).float()
        inter = (p * g).sum((-1, -2))
        denom = p.sum((-1, -2)) + g.sum((-1, -2))
        has = g.sum((-1, -2)) > 0
        if bool(has.any()):
            dice = 1 - (2 * inter[has] + 1) / (denom[has] + 1)
            loss = loss + dice_weight * dice.mean()
    return loss


def row_loss(logits: torch.Tensor, target: torch.Tensor, peak_weight: float = 9.0) -> torch.Tensor:
    """Binary cross entropy of the row head against its Gaussian board bumps, rows near a board weighted up.

    Boards are a few rows in a hundred; weighting by ``1 + peak_weight * target`` keeps the head
    from settling on "no board anywhere".
    """
    w = 1.0 + peak_weight * target
    return F.binary_cross_entropy_with_logits(logits, target, weight=w, reduction="sum") / w.sum()


def column_shifts(cam_x: torch.Tensor, spec: LayoutSpec, j: int, k: int) -> torch.Tensor:
    """Integer column offsets ``(B,)``: frame k's column c shows frame j's column ``c + shift``.

    The shelf-centric frame moves with the camera, so a world point at X sits at
    ``X - cam_x`` in each frame: moving the camera by dx moves content by ``-dx``.
    """
    px = spec.x_extent / spec.size
    return torch.round((cam_x[:, k] - cam_x[:, j]) / px).long()


def consistency_loss(
    logits: torch.Tensor, cam_x: torch.Tensor, visible: torch.Tensor, spec: LayoutSpec, *, long_range: bool
) -> torch.Tensor:
    """Mean L1 between class probabilities of frame pairs after undoing the camera motion.

    Short range compares frame j with j+1; long range compares j with every k >= j+2. Only
    columns both frames see (and inside both layouts) count. Returns 0 when no pair exists.
    """
    b, t, r, c, d, _ = logits.shape
    probs = logits.softmax(3)
    cols = torch.arange(d, device=logits.device)
    total = logits.new_zeros(())
    count = logits.new_zeros(())
    for j in range(t):
        ks = range(j + 2, t) if long_range else range(j + 1, min(j + 2, t))
        for k in ks:
            shift = column_shifts(cam_x, spec, j, k)  # (B,)
            src = cols[None, :] + shift[:, None]  # (B, D): column of frame j for each column of k
            inside = (src >= 0) & (src < d)
            srcc = src.clamp(0, d - 1)
            vis_j = torch.gather(visible[:, j], 1, srcc)
            valid = inside & vis_j & visible[:, k]  # (B, D)
            idx = srcc.view(b, 1, 1, 1, d).expand(b, r, c, d, d)
            pj = torch.gather(probs[:, j], 4, idx)
            diff = (pj - probs[:, k]).abs().sum(2)  # (B, R, D, D) summed over classes
            m = valid.view(b, 1, 1, d).float()
            total = total + (diff * m).sum()
            count = count + m.sum() * r * d
    if float(count) == 0:
        return total
    return total / count


def lsgan_discriminator_loss(d_real: torch.Tensor, d_fake: torch.Tensor) -> torch.Tensor:
    """LSGAN: real -> 1, fake -> 0."""
    return 0.5 * ((d_real - 1).pow(2).mean() + d_fake.pow(2).mean())


def lsgan_generator_loss(d_fake: torch.Tensor) -> torch.Tensor:
    """LSGAN adversarial term for the layout network: make fakes look real (-> 1)."""
    return 0.5 * (d_fake - 1).pow(2).mean()


def one_hot_layouts(target: torch.Tensor, num_classes: int) -> torch.Tensor:
    """``(..., R, D, D)`` ids -> ``(..., R, C, D, D)`` float one-hot (the discriminators' real samples)."""
    return F.one_hot(target, num_classes).movedim(-1, -3).float()
