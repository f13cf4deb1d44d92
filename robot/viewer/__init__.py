"""The Rerun viewer: mapping and navigation runs streamed to a live viewer or an ``.rrd`` file.

* :mod:`robot.viewer.stream`: the command-line flags (``--rerun``, ``--rerun-save``) and the
  recording they open; the SDK is an optional extra (``pip install -e '.[viz]'``);
* :mod:`robot.viewer.scene`: where the map's nodes are drawn and the viewer's layout;
* :mod:`robot.viewer.navigation`: one navigation episode, step by step;
* :mod:`robot.viewer.mapping`: one map being built, frame by frame.

Logging only reads what the run produced: a run with the viewer makes the same decisions as one
without (``tests/test_viewer.py``).
"""
