"""The evaluation report: the report's chapter 7 figures, a Markdown page and
the same page as one self-contained HTML file (figures embedded), from one or
more replay results directories (one per filter mode), side by side.

- ``data``: results loaded (``load``; a long run's epochs decimated) with ``run.json``, and the numbers
  the page and figures show; every time counts from one origin (``data.time_origin``);
- ``figures``: the figures (matplotlib Figure objects, so tests can inspect what each panel holds:
  ``build_figures``; ``figures`` writes them) and their captions, drawn by ``figures_solution`` and
  ``figures_gnss`` with the helpers of ``draw``;
- ``page``: the Markdown and HTML page (``make_report``); ``terminal``: the tables in a terminal.

The truth's biases and clock and the satellites' visibility and sky tracks come from the session's
files (``truth.npz`` and the receiver's ID 23 and ID 22) when they are still there.
"""
