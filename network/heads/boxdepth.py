"""Each box's depth read by a small head, per frame, and carried along the row.

The top-view decoder places a box's front well but reads its back (its depth along Z) poorly: a
box's depth shows in an image only through a top face, a side face in a gap or its back edge
(`waresynth.visibility`), and `research/box_top_faces.py` measured that the true depth of every
box some frame so far showed would lift the 256x256 top-view box mIoU by 14 points.

`BoxDepthHead` reads, per shelf slot, the 1/2-scale pyramid map sampled over the slot's front
window (`WINDOW_ROWS` rows, every column of that map) with the decoder's front-view probabilities
pooled to those rows, then per layout column the decoder's top-view box probabilities along depth,
the camera's height above the board and its distance to the rack front. Per layout column it gives a
distribution over the box's back depth behind the rack front (`BINS`) and the probability that the
frame shows that depth (fitted to `waresynth.visibility` labels; `network.training.fit_box_depth`), the rest
of the network frozen.

`BoxDepthReader` carries the head's readings along the row: per slot, a map over world X (cells of
one model column) that multiplies the distributions of every frame that had the cell in view, each
raised to its shown probability (`RowMap`), the camera's X summed from the steps the images show
(`network.model.motion`). Each frame's ``"box_back"`` ``(R, D)`` is the fused distribution's expected depth
(NaN where the frames have not shown it enough yet); `network.inference.result.frame_layouts` moves every predicted box's back
there (`layouts.boxdepth.impose_box_backs`).

A head fitted with fronts (``front``; the `fit-box-depth` stage's `--front`) also gives, per column, a
distribution over the box's front behind the rack front (`FRONT_BINS`: the stack's setback, a few
centimetres the decoder reads loosely); the reader fuses those the same way, every frame counting once
(a front shows in every frame that sees the box), and each frame's ``"box_front"`` ``(R, D)`` moves
every box's front there.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from layouts import BOX, LayoutSpec
from layouts.canonical import CanonicalView
from network.fastops import mean_row_pairs
from network.heads.parallax import RATIOS, pooled_sweep, relative_costs

BIN_STEP = 0.05  #: metres between the depth bins
BINS = np.arange(0.05, 1.401, BIN_STEP)  #: back depths behind the rack front the head chooses among, metres
FRONT_STEP = 0.02  #: metres between the front bins
#: box fronts behind the rack front (setbacks) a head with fronts chooses among, metres
FRONT_BINS = np.arange(0.0, 0.301, FRONT_STEP)
WINDOW_ROWS = 32  #: rows of the front window sampled from the 1/2 map
#: summed shown probability from which a carried cell's fused depth is used (below it, half a frame's worth
#: of showing, the fused distribution is still near flat and the decoder's depth stays)
MIN_WEIGHT = 0.5
DISTANCE_OFFSET = 1.5  #: metres subtracted from the camera-to-rack distance among the head's inputs
#: frames back that each frame is paired with for the head's parallax inputs (option `box_parallax`)
PARALLAX_BASELINES = (1, 3)
#: parallax maps per frame: per baseline the plane-sweep cost relative to its mean over the planes, and that mean
PARALLAX_CHANNELS = len(PARALLAX_BASELINES) * (len(RATIOS) + 1)


#: the head's channels by default (`BoxDepthHead`)
BOX_WIDTH = 32


def window_rows(layout_size: int) -> int:
    """Rows of a slot's front window for layouts of ``layout_size``: the front view's rows in whole groups."""
    return math.gcd(WINDOW_ROWS, layout_size)


class BoxDepthHead(nn.Module):
    """Per slot: window ``(c2d, WINDOW_ROWS, W)`` + column extras ``(c1d, D)`` -> ``(len(BINS) + 1, D)`` logits
    (the back-depth bins, then the shown logit; with ``front``, then the front bins). A 2-D block over the window, its rows pooled (mean and
    max), then a dilated 1-D block along the columns."""

    def __init__(self, c2d: int, c1d: int, width: int = BOX_WIDTH, front: bool = False) -> None:
        super().__init__()
        self.c2d, self.c1d = c2d, c1d
        self.front = front  #: the logits end with the front bins (`FRONT_BINS`, `split_logits`)

        def block(cin: int, cout: int, dil: tuple[int, int]) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv2d(cin, cout, 3, padding=dil, dilation=dil), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
            )

        self.conv2d = nn.Sequential(block(c2d, width, (1, 1)), block(width, width, (1, 2)), block(width, width, (2, 4)))
        self.conv2d.to(memory_format=torch.channels_last)  # measured: 17 -> 11 ms per frame on 2 CPU threads
        w1 = 2 * width
        pooled = 2 * width

        def block1(cin: int, cout: int, dil: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv1d(cin, cout, 5, padding=2 * dil, dilation=dil), nn.BatchNorm1d(cout), nn.ReLU(inplace=True)
            )

        self.conv1d = nn.Sequential(block1(pooled + c1d, w1, 1), block1(w1, w1, 2), block1(w1, w1, 4))
        self.out = nn.Conv1d(w1, len(BINS) + 1 + (len(FRONT_BINS) if front else 0), 1)

    def forward(self, win: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        x = self.conv2d(win.contiguous(memory_format=torch.channels_last))
        x = torch.cat([x.mean(2), x.amax(2)], 1)  # (N, 2w, W)
        x = F.avg_pool1d(x, x.shape[-1] // extra.shape[-1]) if x.shape[-1] != extra.shape[-1] else x
        return self.out(self.conv1d(torch.cat([x, extra], 1)))


class ParallaxHistory:
    """One sequence's last canonical images and camera steps; `add` gives a frame's plane-sweep costs
    (`network.heads.parallax.pooled_sweep`) against the frames `PARALLAX_BASELINES` back, on the 1/2 map's grid.

    A box's top and side faces lie behind the rack front, so between two frames they move by less than
    the front does (``rho = d / (d + z)`` of it); which swept plane matches tells their depth ``z``. A
    longer baseline moves them apart by more pixels. At a sequence start the earliest frame stands in
    (none at all: zero costs, nothing read)."""

    def __init__(self, view: CanonicalView) -> None:
        self.view = view
        self.images: deque[torch.Tensor] = deque(maxlen=max(PARALLAX_BASELINES) + 1)
        self.steps: deque[float] = deque(maxlen=max(PARALLAX_BASELINES))

    def keep(self, image: torch.Tensor, step: float) -> None:
        """``image`` ``(1, 3, H, W)`` canonical, ``step`` the camera's X motion (metres) since the frame
        before, into the history without making its maps."""
        if self.images:
            self.steps.append(float(step))
        self.images.append(image)

    def add(self, image: torch.Tensor, step: float) -> torch.Tensor:
        """`keep` the frame, then its ``(1, PARALLAX_CHANNELS, H/2, W/2)`` maps."""
        self.keep(image, step)
        maps = []
        for b in PARALLAX_BASELINES:
            j = min(b, len(self.images) - 1)
            prev = self.images[-1 - j]
            dx = torch.tensor([sum(list(self.steps)[-j:]) if j else 0.0], device=image.device)
            maps.append(pooled_sweep(image.float(), prev.float(), dx, self.view))
        return torch.cat([relative_costs(m) for m in maps], 1)  # pooled first: both steps are linear


def head_inputs(
    window: torch.Tensor, top: torch.Tensor, front: torch.Tensor, anchors: torch.Tensor, view: CanonicalView,
    distance: float, parallax: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """One frame's head inputs: window ``(R, c1 + 3 [+ P], WINDOW_ROWS, W)`` and extras ``(R, D + 2, D)``, float32.

    ``window``: ``(R, c1, WINDOW_ROWS, W)`` 1/2-map samples (`network.model.decoders.SlotHeads.window`);
    ``top``/``front``: ``(R, 3, D, D)`` logits (box offsets applied); ``anchors``: ``(R,)`` canonical rows
    (NaN: no slot); ``distance``: camera to rack front, metres; ``parallax``: `ParallaxHistory` maps
    sampled the same way, ``(R, P, WINDOW_ROWS, W)`` (option `box_parallax`). Rounded through fp16, as
    the head is fitted on an fp16 cache."""
    d = top.shape[-1]
    a = anchors.float()
    a = torch.where(torch.isfinite(a), a, torch.full_like(a, view.height / 2))
    fr = torch.softmax(front.float(), 1)  # (R, 3, D, D), rows top to bottom of the window
    rows = window.shape[-2]
    fr = mean_row_pairs(fr) if fr.shape[-2] == 2 * rows else F.adaptive_avg_pool2d(fr, (rows, d))
    fr = fr.repeat_interleave(window.shape[-1] // d, -1)
    tb = torch.softmax(top.float(), 1)[:, BOX]  # (R, D depth rows, D columns)
    elev = ((a - view.height / 2) * view.metres_per_pixel).view(-1, 1, 1).expand(-1, 1, d)
    dist = torch.full_like(elev, distance - DISTANCE_OFFSET)
    win = torch.cat([window.float(), fr] + ([] if parallax is None else [parallax.float()]), 1).half().float()
    extra = torch.cat([tb, elev, dist], 1).half().float()
    return win, extra


def frame_head_inputs(
    out: dict[str, torch.Tensor], view: CanonicalView, distance: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """`head_inputs` of one `network.inference.predictor.Predictor` output (its box window, logits, anchors and, for a
    head that reads them, parallax maps)."""
    return head_inputs(
        out["box_window"], out["top"], out["front"], out["anchors"], view, distance, out.get("box_parallax")
    )


def split_logits(logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """A head's ``(N, C, D)`` logits -> back-depth bins ``(N, K, D)``, the shown logit ``(N, D)`` and, for a
    head with fronts, the front bins ``(N, F, D)`` (None without)."""
    k = len(BINS)
    if logits.shape[1] not in (k + 1, k + 1 + len(FRONT_BINS)):
        raise ValueError(
            f"box-depth logits must have {k + 1} or {k + 1 + len(FRONT_BINS)} channels, got {logits.shape}"
        )
    return logits[:, :k], logits[:, k], logits[:, k + 1 :] if logits.shape[1] > k + 1 else None


def decode(logits: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """``(R, K+1, D)`` logits -> expected back depth ``(R, D)`` (metres behind the rack front) and the
    probability ``(R, D)`` that the frame shows it."""
    bins, shown, _ = split_logits(logits)
    p = torch.softmax(bins.float(), 1)
    z = (p * torch.as_tensor(BINS, dtype=torch.float32, device=p.device)[None, :, None]).sum(1)
    return z.cpu().numpy(), torch.sigmoid(shown.float()).cpu().numpy()


def reading(logits: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """``(R, K+1, D)`` logits -> what `BoxDepthReader.add` takes: ``(R, K, D)`` log-probabilities of the
    back-depth bins (`BINS`) and the probability ``(R, D)`` that the frame shows the depth."""
    bins, shown, _ = split_logits(logits)
    return torch.log_softmax(bins.float(), 1).cpu().numpy(), torch.sigmoid(shown.float()).cpu().numpy()


def front_reading(logits: torch.Tensor) -> np.ndarray | None:
    """A head's logits -> ``(R, F, D)`` log-probabilities of the front bins (`FRONT_BINS`; None: no fronts)."""
    front = split_logits(logits)[2]
    return None if front is None else torch.log_softmax(front.float(), 1).cpu().numpy()


class RowMap:
    """One slot's box backs along the row: per world-X cell, the sum over the frames that had it in view
    of each frame's bin log-probabilities weighted by its shown probability.

    The fused distribution (that sum, normalised) is a product of the frames' readings: a frame that
    shows the depth sharply outweighs many that guess, and a guess still counts a little where no frame
    has shown anything. Chosen on the tuning sets over the earlier shown-weighted mean of expected depths
    from the frames that said shown (p >= 0.5; docs/network.md, *Fusing the frames' readings*)."""

    def __init__(self, values: np.ndarray = BINS, min_weight: float = MIN_WEIGHT) -> None:
        self.values = np.asarray(values, dtype=np.float64)  #: the bins' depths, metres
        self.min_weight = min_weight  #: summed weight from which a cell's fused depth is used
        self.first = 0  #: world-X cell of row 0 of ``logs``
        self.logs = np.zeros((0, len(self.values)))  #: (cells, K) weighted log-probability sums
        self.weight = np.zeros(0)  #: (cells,) summed shown probabilities

    def _cover(self, cells: np.ndarray) -> None:
        """Grows the arrays to cover ``cells``."""
        lo, hi = int(cells.min()), int(cells.max())
        if not self.weight.size:
            self.first = lo
        before = max(self.first - lo, 0)
        after = max(hi - (self.first + self.weight.size - 1), 0)
        if before or after:
            self.logs = np.pad(self.logs, ((before, after), (0, 0)))
            self.weight = np.pad(self.weight, (before, after))
            self.first -= before

    def add(self, cells: np.ndarray, log_q: np.ndarray, p: np.ndarray) -> None:
        """Adds a frame's columns: world-X ``cells`` ``(D,)``, bin log-probabilities ``log_q`` ``(K, D)``,
        shown probabilities ``p`` ``(D,)``."""
        cells = np.asarray(cells, dtype=np.int64)
        if not cells.size:
            return
        self._cover(cells)
        idx = cells - self.first
        p = np.asarray(p, dtype=np.float64)
        np.add.at(self.logs, idx, (np.asarray(log_q, dtype=np.float64) * p[None]).T)
        np.add.at(self.weight, idx, p)

    def mean(self, cells: np.ndarray) -> np.ndarray:
        """The fused distribution's expected depth at each of ``cells`` (NaN: summed shown probability
        under ``min_weight``, or never in view)."""
        cells = np.asarray(cells, dtype=np.int64)
        out = np.full(cells.shape, np.nan)
        idx = cells - self.first
        ok = (idx >= 0) & (idx < self.weight.size)
        ok[ok] = self.weight[idx[ok]] >= self.min_weight
        if ok.any():
            logs = self.logs[idx[ok]]
            q = np.exp(logs - logs.max(1, keepdims=True))
            out[ok] = (q @ self.values) / q.sum(1)
        return out

    def update(self, cells: np.ndarray, log_q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """`add`, then the map's `mean` at the same cells."""
        self.add(cells, log_q, p)
        return self.mean(cells)


class BoxDepthReader:
    """One sequence's (one rack row's) carried box depths: `add` a frame's head output and camera step,
    get its ``(R, D)`` back depths (metres behind the rack front, `RowMap`; NaN: not shown enough yet).

    `backs` looks the maps up for any camera position later, so a reader fed a whole sequence gives
    every frame what all the frames showed (`network.inference.predictor.Predictor`, ``whole_sequence``).
    """

    def __init__(self, spec: LayoutSpec, make_map: Callable[[], RowMap] = RowMap) -> None:
        self.spec = spec  #: the model's layouts (the head's columns)
        self.make_map = make_map  #: one slot's map (`RowMap`; research/box_fusion.py passes other rules)
        self.camera_x = 0.0  #: metres along the row since the first frame
        self.maps: dict[int, RowMap] = {}
        self.front_maps: dict[int, RowMap] = {}  #: per slot, the fronts of a head with fronts (`FRONT_BINS`)

    def cells(self, camera_x: float) -> np.ndarray:
        """The world-X cell of each layout column's centre with the camera at ``camera_x``."""
        width = self.spec.x_extent / self.spec.size
        # floor: centres sit mid-cell, never on a boundary
        return np.floor((camera_x + self.spec.col_to_x(np.arange(self.spec.size) + 0.5)) / width).astype(int)

    def add(
        self, log_q: np.ndarray, p: np.ndarray, valid: np.ndarray, step: float = 0.0, front: np.ndarray | None = None
    ) -> np.ndarray:
        """``log_q`` ``(R, K, D)``, ``p`` ``(R, D)``: the head's bin log-probabilities and shown probabilities
        (`reading`); ``valid`` ``(R,)``: slots with an anchor; ``step``: the camera's
        motion along X since the previous frame (metres); ``front``: a head's front-bin log-probabilities
        ``(R, F, D)`` (`front_reading`), each frame's counted once. Returns `backs` here."""
        self.camera_x += float(step)
        cells = self.cells(self.camera_x)
        for r in np.nonzero(valid)[0]:
            self.maps.setdefault(int(r), self.make_map()).add(cells, log_q[r], p[r])
            if front is not None:
                self.front_maps.setdefault(int(r), RowMap(FRONT_BINS)).add(cells, front[r], np.ones(len(cells)))
        return self.backs(self.camera_x, valid)

    def backs(self, camera_x: float, valid: np.ndarray) -> np.ndarray:
        """``(R, D)`` fused back depths the maps hold for the slots ``valid`` with the camera at ``camera_x``."""
        return self._look_up(self.maps, camera_x, valid)

    def fronts(self, camera_x: float, valid: np.ndarray) -> np.ndarray | None:
        """``(R, D)`` fused box fronts behind the rack front, as `backs` (None: the head reads no fronts)."""
        return self._look_up(self.front_maps, camera_x, valid) if self.front_maps else None

    def _look_up(self, maps: dict[int, RowMap], camera_x: float, valid: np.ndarray) -> np.ndarray:
        cells = self.cells(camera_x)
        out = np.full((len(valid), self.spec.size), np.nan)
        for r in np.nonzero(valid)[0]:
            m = maps.get(int(r))
            if m is not None:
                out[r] = m.mean(cells)
        return out
