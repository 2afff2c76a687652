"""pmetric: differentiable JAX models of human contrast sensitivity and visual acuity.

Every model answers two questions, vectorized and differentiable:

* is this change visible?  (``model.is_perceptible(c, f, e, v)``)
* from what viewing distance does it stop being visible?  (``model.imperceptible_distance(c, theta, e, v)``)

Units throughout: spatial frequency ``f`` in cycles/deg, eccentricity ``e`` in deg,
retinal velocity ``v`` in deg/s, Michelson contrast ``c`` in [0, 1], luminance in cd/m2.

Models by name: ``make_model("stela")``, ``make_model("eccentric(manossakrison)")``,
``make_model("fitted.json")``; ``default_model()`` is :data:`DEFAULT_MODEL` (stelaCSF, published constants). Names
are case-insensitive; ``model_entries()`` (and ``plod models``) list them with inputs and constants.
"""

# Each private module adds its public names below (one import line per module).
from ._errors import PlodError
from ._atomic import atomic_path, atomic_write_bytes, atomic_write_text
from ._base import CSFModel
from ._manos_sakrison import ManosSakrison
from ._kelly import KellyAbstract, KellySpatioTemporal
from ._eccentric import Eccentric, RovamoVirsu
from ._acuity import ReddyAcuity
from ._inverse import lambertw_m1
from ._display import Display, linear_to_srgb, michelson, michelson_range, relative_luminance, srgb_to_linear
from ._barten import Barten
from ._stela import StelaCSF
from ._table import CalibratedCSF
from ._registry import DEFAULT_MODEL, ModelEntry, default_model, make_model, model_entries, model_registry, register_model
from ._serialize import load_model, model_from_dict, model_to_dict, save_model
