"""pmetric: differentiable JAX models of human contrast sensitivity and visual acuity.

Every model answers two questions, vectorized and differentiable:

* is this change visible?  (``model.is_perceptible(c, f, e, v)``)
* from what viewing distance does it stop being visible?  (``model.imperceptible_distance(c, theta, e, v)``)

Units throughout: spatial frequency ``f`` in cycles/deg, eccentricity ``e`` in deg,
retinal velocity ``v`` in deg/s, Michelson contrast ``c`` in [0, 1], luminance in cd/m2.
"""

# Each private module adds its public names below (one import line per module).
from ._atomic import atomic_path, atomic_write_bytes, atomic_write_text
