"""The runner's commands, one module each (training/run.py assembles them): recognize and incremental
(:mod:`.recognize`), evaluate, robustness, tradeoff and salient; grasp is training/grasping/command.py."""
