"""Fit the shipped skin model (tracker/hands/skin_model.json) on the UCI skin data in ../shared.

    .venv/bin/python scripts/fit_skin_model.py [--log-tau X]

Training half and test half exactly as the data's README (``default_rng(0).permutation``, first 122,528 rows
train); the skin GMM has 2 components, the generic non-skin GMM 2 (the README's "GMM k=2, LR > 1" baseline).
The test-half accuracy / TPR / FPR are printed and stored in the file's ``info``, beside the box rule's.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tracker.hands.skin_model import MODEL_PATH, Gmm2D, SkinModel, crcb  # noqa: E402
from tracker.shared_data import skin_data_path  # noqa: E402

N_TRAIN = 122528


def load_split() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(Cr, Cb) and labels of the training and test halves."""
    path = skin_data_path()
    if not path.is_file():
        raise SystemExit(f"skin data not found: {path} (the shared folder must be beside the checkout)")
    with np.load(path) as z:
        bgr = np.asarray(z["bgr"], np.uint8)
        label = np.asarray(z["label"], np.uint8)
    x = crcb(bgr[:, ::-1].reshape(-1, 1, 3)).reshape(-1, 2)
    perm = np.random.default_rng(0).permutation(len(label))
    tr, te = perm[:N_TRAIN], perm[N_TRAIN:]
    return x[tr], label[tr], x[te], label[te]


def rates(pred: np.ndarray, label: np.ndarray) -> dict:
    pred = pred.astype(bool)
    pos = label == 1
    return {
        "accuracy": float(np.mean(pred == pos)),
        "tpr": float(np.mean(pred[pos])),
        "fpr": float(np.mean(pred[~pos])),
    }


def box_rule(x: np.ndarray) -> np.ndarray:
    """Algorithm 1's YCbCr rule: 133 ≤ Cr ≤ 173 and 77 ≤ Cb ≤ 127."""
    return (x[:, 0] >= 133) & (x[:, 0] <= 173) & (x[:, 1] >= 77) & (x[:, 1] <= 127)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log-tau", type=float, default=0.0, help="LRT threshold log τ stored in the file (default 0)")
    ap.add_argument("--out", default=str(MODEL_PATH))
    args = ap.parse_args()
    xtr, ytr, xte, yte = load_split()
    skin = Gmm2D.fit(xtr[ytr == 1], 2, seed=0)
    nonskin = Gmm2D.fit(xtr[ytr == 0], 2, seed=0)
    model = SkinModel(skin, nonskin, args.log_tau)
    ours = rates(model.classify(xte), yte)
    base = rates(box_rule(xte), yte)
    info = {
        "data": "UCI Skin Segmentation (Bhatt & Dhall 2012, CC BY 4.0), ../shared/data/external/skin",
        "split": "default_rng(0).permutation; first 122528 rows train, rest test",
        "test_gmm": ours,
        "test_box_rule": base,
        "fitted_by": "scripts/fit_skin_model.py",
    }
    SkinModel(skin, nonskin, args.log_tau, info=info).save(args.out)
    print(f"wrote {args.out}")
    print(f"test half: GMM k=2 LRT  acc {ours['accuracy']:.4f} TPR {ours['tpr']:.4f} FPR {ours['fpr']:.4f}")
    print(f"           box rule     acc {base['accuracy']:.4f} TPR {base['tpr']:.4f} FPR {base['fpr']:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
