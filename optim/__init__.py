"""optim: vertex hierarchies, per-view perceptual scoring, simplification cuts and model fitting.

Stages (one file each): build hierarchy (``_tree``) -> view (``_view``) -> score folds (``_score``)
-> rank and select (``_cut``) -> extract; fitting of model constants in ``_fit``.
"""

# Each private module adds its public names below (one import line per module).
from ._fit import FitResult, expressible_rows, fit_least_squares, fitted_fields
from ._mesh import MeshReport, bumpy_sphere, bumpy_torus, grid_mesh, icosphere, load_mesh, save_mesh, validate_mesh
from ._tree import Lighting, VertexTree, build_tree, load_tree, mesh_hash, normal_cell_directions, normal_cells, vertex_luminance
from ._cut import Cut, budget_cut, budget_cut_heap, extract, repair_monotone, threshold_cut
from ._view import View
from ._score import NodeTerms, ScoringContext, imperceptible_cut, node_terms, score, scoring_context, default_model
from ._mcmc import ChainTooShortWarning, LogUniform, Normal, Posterior, Uniform, conservative, fit_mcmc
