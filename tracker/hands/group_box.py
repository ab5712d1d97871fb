"""Two stacked hands reported as one group (product addition, ``HandTrackerConfig.group_box``): the merge handling of
blob trackers (tracking a merged group as one region until it splits, e.g. McKenna et al. 2000).

When one hand lies on top of the other, the two hands' skin forms one colour component hardly larger than one hand;
the top hand hides most of the lower one, whose ground-truth palm box is the box of its visible scraps beside and
under the top hand. Neither track can tell the two apart in that component (same skin colour, flow of the top hand
over both), and the two particle filters split the component between them or both sit on one part of it. Then
each track's reported box is the component's tight box: the box that holds both hands, the best single box for
either. The filters themselves go on unchanged (the group box is only reported), so the tracks keep their own
states and ids for when the hands part.

Test (per frame, after the filter steps): both tracks' boxes have the same dominant colour component, not cut by
the ROI, and its box is at most :data:`GROUP_AREA` times the larger of the two tracks' one-hand box areas (running
means of their box areas while apart, ``_Track.area_apart``). Ground-truth check on tuning seeds 0–4 of
``hands-s2`` (the union of the two palm boxes, given to both hands whenever it is at most r times the larger palm
box): F̄^b of the tracker's run 0.708 → 0.717 / 0.757 / 0.768 / 0.779 / 0.776 / 0.764 at r = 1.2 / 1.4 / 1.6 / 1.8 /
2.0 / 2.5. In the tracker (with the exclusion, filter seeds 0, 1; component boxes and one-hand areas are the
tracker's): F̄^b 0.708 without the group box, 0.724 / 0.749 / 0.752 with GROUP_AREA 1.8 / 2.4 / 3.0 (the frames of
heavy overlap gain, those of light overlap lose 0.001–0.003); 2.4 taken. Without the exclusion, eight filter seeds
(40 runs): F̄^b 0.697 → 0.729, ē^p 22.2 → 21.7 px, better on both halves of the filter seeds (0–3 and 4–7).
Boxes inclusive, working pixels of the tracker's ROI unless stated.
"""

from __future__ import annotations

import numpy as np

from tracker.hands.box_stats import box_area, box_of, dominant_component

GROUP_AREA = 2.4
"""Largest area of the shared component's box, in units of the larger one-hand box area, for the group box."""


def group_component(states: list[np.ndarray], one_hand: list[float], cc: np.ndarray, n_comp: int,
                    cc_box: np.ndarray, cc_cut: np.ndarray, origin: tuple[int, int],
                    max_area: float = GROUP_AREA) -> tuple[int, int, int, int] | None:  # fmt: skip
    """The shared component's inclusive box in image (working) px if two tracks form a group, else None.

    ``states``: the two tracks' estimates (x, y, w, h, …) in image px; ``one_hand``: their one-hand box areas (px²,
    0 = unknown: no group); ``cc`` / ``n_comp`` / ``cc_box`` / ``cc_cut``: the ROI's colour components
    (:func:`tracker.hands.features.components`); ``origin``: the ROI's top-left pixel (x, y) in the image."""
    if len(states) != 2 or min(one_hand) <= 0:
        return None
    ox, oy = origin
    labs = []
    for e in states:
        u0, v0, u1, v1 = box_of(float(e[0]) - ox, float(e[1]) - oy, float(e[2]), float(e[3]))
        labs.append(dominant_component(u0, v0, u1, v1, cc, n_comp)[0])
    lab = labs[0]
    if lab == 0 or labs[1] != lab or cc_cut[lab]:
        return None
    b = cc_box[lab]
    if box_area(b) > max_area * max(one_hand):
        return None
    return int(b[0]) + ox, int(b[1]) + oy, int(b[2]) + ox, int(b[3]) + oy
