"""Checkpoints that cannot run code: the format and manifest (``manifest``), the model's tensors and state
(``model_state``), what an exact resume needs (``resume``), saving and finding checkpoints (``store``), loading
(``load``); ``sb3_compat`` reads SB3's pickle-based files, only with an explicit trust_pickle."""
