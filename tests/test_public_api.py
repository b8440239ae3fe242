"""The public names users import exist (an import smoke test)."""

import jaxnav
from jaxnav import core
from jaxnav.localization import mcl
from jaxnav.models import landmarks, motion


def test_public_names():
    assert isinstance(jaxnav.__version__, str)
    for name in [
        "normalize",
        "ess",
        "log_ess",
        "log_marginal_increment",
        "weighted_mean",
        "weighted_cov",
        "circular_mean",
        "particle_mean",
        "multinomial",
        "systematic",
        "stratified",
        "residual",
        "conditional_resample",
        "gaussian_refresh",
        "ring_init",
        "ring_push",
        "ring_ordered",
        "ring_mean",
        "monte_carlo",
    ]:
        assert callable(getattr(core, name)), name
    for name in ["init", "init_uniform", "step", "run", "MCLConfig", "MCLParams", "MCLState", "MCLInfo"]:
        assert hasattr(mcl, name), name
    assert set(motion.MODELS) == {"velocity", "odometry", "omni", "omni_body"}
    assert set(core.SCHEMES) == {"multinomial", "systematic", "stratified", "residual"}
    assert hasattr(landmarks, "RangeBearingObs")
