"""The SPTM-style learned action baseline (the paper's comparison method).

Same localisation, planning and node switching as our navigator; only the action comes from a
classifier trained on exploration data instead of the Left / Middle / Right voter:

* :mod:`~robot.baseline.features`: frozen EfficientNet-Lite0 features of thumbnail-sized images;
* :mod:`~robot.baseline.track`: progress along the walkthrough (what "ahead" means);
* :mod:`~robot.baseline.expert`: the ground-truth expert's target nodes and LEFT / FORWARD / RIGHT labels;
* :mod:`~robot.baseline.exploration`: exploration drives in the simulator that collect samples;
* :mod:`~robot.baseline.head`: the MLP classifier and its file;
* :mod:`~robot.baseline.fit`: training with a fixed seed and accuracy statistics;
* :mod:`~robot.baseline.policy`: :class:`SptmPolicy`, the ``ActionPolicy`` for navigation episodes;
* :mod:`~robot.baseline.pipeline`: :func:`train_baseline` / :func:`load_baseline`.

Usage::

    path = train_baseline("hospital", "runs/hospital/map", "runs/baseline.pt", episodes=40, seed=0)
    policy = SptmPolicy(load_baseline(path), load_map("runs/office/map"))
    run_sim_navigation(SimEpisode("office", "runs/office/map", route="main"), descriptor, action_policy=policy)
"""

from robot.baseline.head import BaselineFileError, TrainedHead
from robot.baseline.pipeline import BaselineInputError, build_baseline, load_baseline, train_baseline
from robot.baseline.policy import SptmPolicy

__all__ = ["BaselineFileError", "BaselineInputError", "SptmPolicy", "TrainedHead", "build_baseline",
           "load_baseline", "train_baseline"]
