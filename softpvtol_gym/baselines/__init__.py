"""The baselines as a library (installed with the ``baselines`` extra): training, checkpoints, the
leaderboard, figures, and the ``softpvtol`` console command (:mod:`softpvtol_gym.baselines.cli`).

Subpackages, imports pointing down only: ``util`` (atomic writes, locks, paths, generated Markdown blocks,
argument parsing, optional extras) and ``errors``; ``config`` (hyperparameter YAML, validation, the run
config); ``evaluation``; ``training`` (models, the train loop, :class:`~.training.policy.LearnedPolicy`,
:class:`~.training.lean.LeanMLPPolicy`);
``checkpoints`` (the safe format; ``sb3_compat`` is the only place that unpickles); ``leaderboard`` (jobs,
Ray executor, statistics, rendering); ``figures``; ``commands`` (one module per subcommand); ``cli``.
Importing this package imports none of them; a policy of your own is scored on the leaderboard's episodes and
ranked among its entries by :func:`softpvtol_gym.baselines.leaderboard.score.score`.
"""
