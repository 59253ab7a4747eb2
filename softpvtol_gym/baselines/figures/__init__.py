"""Figures: tracking plots and learning curves (``tracking``), episode GIFs (``gif``), the paper model's
integration error (``model``)."""
