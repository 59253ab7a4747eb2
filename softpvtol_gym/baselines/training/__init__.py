"""Training: SB3 models on the native vector env (``models``), the train loop with checkpoints and exact
resume (``loop``), and :class:`~.policy.LearnedPolicy` (``policy``)."""
