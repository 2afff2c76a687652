"""optim: vertex hierarchies, per-view perceptual scoring, simplification cuts and model fitting.

Pipeline, one home per concept: mesh input and its bad-input policy (``_mesh``) -> build the hierarchy
(``_tree``, built by ``_build``; clustering in ``_meshopt_tree`` (default) / ``_qem`` / ``_octree``, normal cube in
``_normal_cube``, level-by-level propagation in ``_levels``) -> view (``_view``, with its lights) -> score folds
(``_score``: classify -> terms -> key -> propagate, over the per-tree ``_context``, what a renderer shows in
``_relight`` and the per-node ``_terms``) -> select and extract (``_cut``; flips in ``_flips``; the normals a cut carries in ``_normals``; per-view back-face removal and the budget cut that counts
only front-facing triangles in ``_facecull``; discrete levels of detail for any view direction, with their switch sizes, in
``_lods``); fitting of model
constants in ``optim.fit``. Beside the meshes: the perceptual point-hierarchy traversal of [LH01 §4] / [RL00] in
``_points``, and Reddy's perceptual terrain quadtree [Red01] in ``_terrain``.
"""

# Each private module adds its public names below (one import line per module).
from .fit import FitResult, expressible_rows, fit_least_squares, fitted_fields
from ._mesh import MeshReport, ValidatedMesh, load_mesh, save_mesh, validate_mesh
from ._shapes import bumpy_sphere, bumpy_torus, grid_mesh, icosphere
from ._normal_cube import normal_cell_directions, normal_cells
from ._tree import Lighting, VertexTree, load_tree, local_origin, mesh_hash, vertex_luminance
from ._build import build_tree
from ._meshopt_tree import MeshoptHierarchy, meshopt_parents
from ._cut import (Cut, budget_cut, budget_cut_heap, extract, imperceptible_cut, min_nonempty_budget, repair_monotone,
                   threshold_cut)
from ._flips import Flips, cut_flips
from ._normals import NORMALS, cut_normals, region_normals
from ._facecull import VisibleCut, drop_back_faces, facing_away, visible_budget_cut
from ._view import View, framing_sphere
from ._lods import (LevelOfDetail, direction_keys, lod_chain, lod_sizes, max_object_deg, object_distance, screen_fraction,
                    sphere_directions)
from ._context import CONTEXT_NAMES, ScoringContext, load_context, save_context, scoring_context
from ._relight import cull_columns, neighbour_normals, normal_cones, region_columns, relit_columns, slab_half_width
from ._score import NodeTerms, node_terms, score, default_model, prepare_motion_table
from ._points import (PointHierarchy, PointTerms, Traversal, build_points, load_points, point_terms, points_from_mesh,
                      save_points, splat_discs, traverse, walk)
from ._terrain import (Heightfield, TerrainCamera, TerrainCriteria, TerrainLOD, crop_heightfield, fractal_heightfield,
                       full_mesh, refine_terrain, terrain_mesh)
from .fit import ChainTooShortWarning, LogUniform, Normal, Posterior, Uniform, conservative, fit_mcmc
