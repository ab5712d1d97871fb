"""Track identity of the hand tracker (:class:`tracker.hands.tracker.HandTracker`): which hand each track follows.

The rules are stated in :mod:`tracker.hands.tracker`'s docstring (two hands on top of each other, shared regions,
re-acquisition, id swaps, when appearance is learnt); the appearance model itself is :mod:`tracker.hands.identity`.
:class:`TrackIdentity` holds the methods that apply them; it is a part of ``HandTracker`` and works on its state:
``tracks`` and ``lost`` (live and ended tracks), ``frame_index``, ``_cur_rgb``, the colour-bin images ``_bins`` and
``_bg_bins``, ``_frame_mask`` and ``_start``. Boxes are inclusive, in working pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from tracker.hands import identity
from tracker.hands.track_boxes import box_f_score, boxes_overlap, inside_fraction, state_box

APART_F = 0.5
"""Box F-score with every other track below which a track counts as following a hand of its own."""
ESTABLISHED = 5
"""Frames a track must have spent apart (:data:`APART_F`) for a later duplicate of it to count as a second hand."""
SHARED_FRAC = 0.5
"""Two tracks share a region when this fraction of one's box lies inside the other's (a free hand may take one)."""
SETTLE = 15
"""Frames after two tracks part during which their appearance is not learnt (their ids may still be swapped)."""
ALONE_EVERY = 3
"""A lone track's appearance is learnt on every ALONE_EVERY-th frame only (it costs a colour-bin image per frame)."""
SWAP_FRAMES = 3
"""Consecutive frames the exchanged id assignment must fit better before two tracks' ids are swapped."""


class TrackIdentity:
    """Identity methods of :class:`tracker.hands.tracker.HandTracker` (module docstring)."""

    def _undo_jumps(self, before: list[tuple[dict, tuple[int, int, int, int]]]) -> None:
        """A track that lands in one step on the box of another track it was apart from (box F-score < APART_F the
        frame before, ≥ APART_F now) jumped hands (e.g. a section-6 box of the other hand's colour component): the
        one that moved farther (in units of its box size) is put back and moved by its velocity instead."""
        n = len(self.tracks)
        now = [state_box(tr.filt.estimate) for tr in self.tracks]
        for i in range(n):
            for j in range(i + 1, n):
                if box_f_score(before[i][1], before[j][1]) >= APART_F or box_f_score(now[i], now[j]) < APART_F:
                    continue
                moved = []
                for k in (i, j):
                    b0, b1 = before[k][1], now[k]
                    d = np.hypot(0.5 * (b1[0] + b1[2] - b0[0] - b0[2]), 0.5 * (b1[1] + b1[3] - b0[1] - b0[3]))
                    moved.append(d / max(b0[2] - b0[0] + 1, b0[3] - b0[1] + 1, 1))
                k = i if moved[0] >= moved[1] else j
                filt = self.tracks[k].filt
                filt.__dict__.update(before[k][0])
                filt.coast()
                now[k] = state_box(filt.estimate)

    def _bin_image(self, rgb: np.ndarray) -> np.ndarray:
        return identity.bin_image(cv2.cvtColor(rgb, cv2.COLOR_RGB2YCrCb))

    def _appearance(self, rgb: np.ndarray, state: np.ndarray) -> np.ndarray | None:
        """Appearance histogram around a working-resolution state's box in this frame."""
        if self._bg_bins is None:
            return None
        if self._bins is None:
            self._bins = self._bin_image(rgb)
        return identity.appearance(self._bins, self._frame_mask(rgb), self._bg_bins, state_box(state))

    def _duplicate_loser(self, i: int, j: int) -> int:
        """Index of the one of two duplicate tracks whose appearance fits their shared box worse (ties: the
        younger)."""
        a, b = self.tracks[i], self.tracks[j]
        if a.app is not None and b.app is not None:
            assert self._cur_rgb is not None
            obs = self._appearance(self._cur_rgb, a.filt.estimate)
            sa, sb = identity.similarity(a.app, obs), identity.similarity(b.app, obs)
            if abs(sa - sb) > 0.05:
                return j if sa > sb else i
        return j if b.id > a.id else i

    def _shared_pair(self) -> tuple[int, int] | None:
        """Indices of two live tracks on one region: their boxes overlap by at least SHARED_FRAC of the smaller box
        (two hands on top of each other, or two tracks on one hand)."""
        boxes = [state_box(tr.filt.estimate) for tr in self.tracks]
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                if max(inside_fraction(boxes[i], boxes[j]), inside_fraction(boxes[j], boxes[i])) >= SHARED_FRAC:
                    return i, j
        return None

    def _transfer(self, pair: tuple[int, int], state: np.ndarray, rgb: np.ndarray) -> int:
        """A skin region no track explains appeared while two tracks share one region: the one whose appearance fits
        the new region better restarts there with its id (without a clear appearance answer: the one whose box lies
        more inside the other's, then the younger); returns that id."""
        a, b = self.tracks[pair[0]], self.tracks[pair[1]]
        obs = self._appearance(rgb, state)
        sa, sb = identity.similarity(a.app, obs), identity.similarity(b.app, obs)
        ba, bb = state_box(a.filt.estimate), state_box(b.filt.estimate)
        ia, ib = inside_fraction(ba, bb), inside_fraction(bb, ba)
        if a.app is not None and b.app is not None and obs is not None and abs(sa - sb) > 0.05:
            mover = a if sa > sb else b
        elif abs(ia - ib) > 0.1:
            mover = a if ia > ib else b
        else:
            mover = b if b.id > a.id else a
        stay = b if mover is a else a
        self.tracks.remove(mover)
        self._start(state, mover.id)
        new = self.tracks[-1]
        new.app, new.since_merge, new.apart = mover.app, 0, ESTABLISHED
        stay.merged, stay.dup = False, {}
        stay.since_merge = 0
        return mover.id

    def _pick_lost(self, state: np.ndarray, rgb: np.ndarray) -> int:
        """Index of the lost track a re-acquired hand at ``state`` continues: the best appearance match if the lost
        tracks have appearance models and the hand has an appearance measurement, else the one last seen nearest."""
        obs = self._appearance(rgb, state)
        sims = [identity.similarity(lo.app, obs) for lo in self.lost]
        if obs is not None and any(lo.app is not None for lo in self.lost) and max(sims) - min(sims) > 0.05:
            return int(np.argmax(sims))
        d = [np.hypot(*(lo.state[:2] - state[:2])) for lo in self.lost]
        return int(np.argmin(d))

    def _identity(self, rgb: np.ndarray) -> None:
        """Swap back ids that moved to the other hand, then learn the isolated tracks' appearance (a lone track with
        no lost track waiting only every ALONE_EVERY-th frame: there is nothing to tell apart yet)."""
        n = len(self.tracks)
        if n == 1 and not self.lost and self.frame_index % ALONE_EVERY:
            return
        boxes = [state_box(tr.filt.estimate) for tr in self.tracks]
        obs = [self._appearance(rgb, tr.filt.estimate) for tr in self.tracks]
        isolated = []
        for i in range(n):
            b = boxes[i]
            gap = self.config.isolation_margin
            mx, my = gap * (b[2] - b[0] + 1), gap * (b[3] - b[1] + 1)
            big = (b[0] - mx, b[1] - my, b[2] + mx, b[3] + my)
            isolated.append(obs[i] is not None and not any(
                boxes_overlap(big, boxes[j]) for j in range(n) if j != i))  # fmt: skip
        sim = identity.similarity
        for i in range(n):
            for j in range(i + 1, n):
                a, b = self.tracks[i], self.tracks[j]
                held = a.hold_id or b.hold_id  # a track restarted beside what hid its hand (HandTracker)
                if not (isolated[i] and isolated[j] and a.app is not None and b.app is not None) or held:
                    a.swap.pop(b.id, None)
                    continue
                gain = sim(a.app, obs[j]) + sim(b.app, obs[i]) - sim(a.app, obs[i]) - sim(b.app, obs[j])
                a.swap[b.id] = a.swap.get(b.id, 0) + 1 if gain > identity.SWAP_MARGIN else 0
                if a.swap[b.id] >= SWAP_FRAMES:
                    a.id, b.id = b.id, a.id
                    a.app, b.app = b.app, a.app
                    a.swap, b.swap = {}, {}
                    a.dup, b.dup = {}, {}
        for i, tr in enumerate(self.tracks):
            if not isolated[i] or tr.app is None:
                continue
            for lo in self.lost:
                if lo.app is None:
                    continue
                gain = sim(lo.app, obs[i]) - sim(tr.app, obs[i])
                key = -lo.id
                tr.swap[key] = tr.swap.get(key, 0) + 1 if gain > identity.SWAP_MARGIN / 2 else 0
                if tr.swap[key] >= SWAP_FRAMES:
                    tr.id, lo.id = lo.id, tr.id
                    tr.app, lo.app = lo.app, tr.app
                    tr.swap = {}
                    break
        for tr in self.tracks:
            tr.hold_id = max(tr.hold_id - 1, 0)
        for i, tr in enumerate(self.tracks):
            settled = tr.since_merge >= SETTLE and not tr.merged and not self.lost
            if isolated[i] and settled and tr.score >= 0.5 and not any(v > 0 for v in tr.swap.values()):
                assert obs[i] is not None
                if tr.app is not None and sim(tr.app, obs[i]) < identity.LEARN_MIN_SIM:
                    continue  # not the hand the model was learnt on (or its look changed): keep the model as it is
                tr.app = identity.learn(tr.app, obs[i])
