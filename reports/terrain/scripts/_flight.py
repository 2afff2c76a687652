"""The Table 1 timing setup shared by the terrain timing scripts: the 1025 x 1025 fractal (10 m spacing,
600 m relief), the flight of ``configs/terrain_flight.toml`` and the display's xi (1280 px across its
field), as ``experiments.terrain`` builds them."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from experiments.terrain import FLIGHT, flight_cameras, load_config, repo_path  # noqa: E402
from optim._terrain import Heightfield, fractal_heightfield  # noqa: E402


def table1_flight():
    """(heightfield, cameras, xi cycles/deg, dt s, flight dict)."""
    hf = Heightfield(fractal_heightfield(1025, seed=0, relief=600.0), 10.0)
    fl = load_config(repo_path("configs/terrain_flight.toml"), FLIGHT)
    return hf, flight_cameras(hf, fl), 1280 / (2.0 * fl["fov_deg"][0]), 1.0 / fl["fps"], fl
