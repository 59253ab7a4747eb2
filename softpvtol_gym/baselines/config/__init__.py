"""Run configuration: hyperparameter YAML per env id and CLI overrides (``hyperparams``), their validation
(``validation``), and :class:`~.run_config.RunConfig` (``run_config``)."""
