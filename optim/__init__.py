"""optim: vertex hierarchies, per-view perceptual scoring, simplification cuts and model fitting.

Stages (one file each): build hierarchy (``_tree``) -> view (``_view``) -> score folds (``_score``)
-> rank and select (``_cut``) -> extract; fitting of model constants in ``_fit``.
"""

# Each private module adds its public names below (one import line per module).
