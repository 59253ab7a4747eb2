"""The leaderboard: the job list and its runs (``jobs``), the Ray executor (``ray_executor``), the statistics
(``stats``, rliable), the headline (``headline``) and the Markdown page and chart (``render``)."""
