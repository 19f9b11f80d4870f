"""The learned features as pictures: figures 4.7, 4.8 and 5.2."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ftorch.recognition.environment import ImageSet
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.space.draw import draw_features, feature_legend, grid, save_rgb, titled
from training.cli.outputs import Ledger


def class_files(label) -> tuple[str, str]:
    """The files a fold writes named after class ``label``: its figure 4.8 and its network's BIF."""
    return f"{label}_features.png", f"{label}.bif"


def feature_pictures(learner: DistinctiveFeatureLearner, env: ImageSet, heading: str = "learned features",
                     views: int | None = None) -> list[tuple[str, np.ndarray]]:
    """Figure 4.7 / 5.2 ("features": each class's features present in its middle training view)
    and figure 4.8 ("<class>_features": the first class's features in every training view of it
    where they are present), as (name, RGB uint8 picture), titled with ``heading`` (task, seed, fold).
    Only the first ``views`` images of ``env`` are drawn (all by default; the originals, not the
    augmented copies that follow them)."""
    pictures, panels = [], []
    shown = env.labels[:views]

    def present(label, image: int) -> tuple[list, list[int]]:
        net = learner.networks[label]
        values = env.values(net.features, [image])[:, 0] if net.features else np.zeros(0)
        keep = [k for k, f in enumerate(net.features) if values[k] > net.threshold[f]]
        return [net.features[k] for k in keep], [k + 1 for k in keep]

    classes = sorted(learner.networks, key=str)
    for label in classes:
        of_class = [i for i, labels in enumerate(shown) if label in labels]
        if of_class:
            middle = of_class[len(of_class) // 2]
            features, ids = present(label, middle)
            panels.append(titled(draw_features(env.all_records, middle, env.images[middle], features, ids, legend=True),
                                 f"{label}: {len(features)} of {len(learner.networks[label].features)} present"))
    if panels:
        pictures.append(("features", titled(grid(panels, min(4, len(panels))),
                                            f"{heading}: each class's features present in its middle training view")))
    if classes:
        first = classes[0]
        of_class = [i for i, labels in enumerate(shown) if first in labels]
        drawn = [titled(draw_features(env.all_records, i, env.images[i], *present(first, i)), env.names[i]) for i in of_class]
        every = grid(drawn, min(5, len(drawn)))
        net = learner.networks[first]
        key = feature_legend(net.features, range(1, len(net.features) + 1), every.shape[1])
        pictures.append((Path(class_files(first)[0]).stem,
                         titled(np.concatenate([every, key]), f"{heading}: {first}'s features in its training views")))
    return pictures


def save_pictures(pictures: list[tuple[str, np.ndarray]], folder: Path, ledger: Ledger) -> list[Path]:
    """Pictures of :func:`feature_pictures` as PNG files ``folder``/<name>.png, recorded in ``ledger`` first."""
    paths = [folder / f"{name}.png" for name, _ in pictures]
    ledger.files(*paths)
    for path, (_, picture) in zip(paths, pictures):
        save_rgb(path, picture)
    return paths
