"""Training: SB3 models on the native vector env (``models``), the train loop with checkpoints and exact
resume (``loop``), and :class:`~.policy.LearnedPolicy` (``policy``): a trained model acting on raw observations,
through :class:`~.lean.LeanMLPPolicy` (``lean``: a compiled float64 forward pass per observation row, the same
action whatever the batch) by default or through torch; ``stacking`` keeps the frame stack of either."""
