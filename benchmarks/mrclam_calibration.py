"""The MRCLAM noise learned on robot 1's first 300 s by MCL and by the EKF, then the known-map filters on
robots 1-3 with the hand-chosen and both learned settings (``jaxnav.experiments.mrclam.calibration``).

``python -m benchmarks.mrclam_calibration [--out benchmarks/results/mrclam_calibration.json]`` prints the
fits and the table and writes them as JSON; it needs the MRCLAM data (``$JAXNAV_DATA``).
``jaxnav mrclam --calibrate mcl`` (or ``ekf``) runs one of the two fits and its comparison.
"""

from __future__ import annotations

import argparse
import json
import time


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.mrclam_calibration", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="benchmarks/results/mrclam_calibration.json", help="JSON file to write")
    args = p.parse_args(argv)

    from jaxnav.experiments import mrclam as xp
    from jaxnav.experiments.mrclam import calibration as cal
    from jaxnav.io import mrclam as data

    s = xp.MRCLAMSettings()
    seq = data.to_filter_steps(data.load_robot(1), dt=s.dt, duration=300.0, max_obs=s.max_obs, keep_outliers=True)
    fits = {}
    for method in cal.METHODS:
        fit = cal.fit_noise(seq, s, method=method)
        fits[method] = fit
        print(
            f"{method}: {fit.seconds:.0f} s, alphas {fit.settings.alphas}, pose_sd {fit.settings.pose_sd}, "
            f"sensor_sd {fit.settings.sensor_sd}, loss {fit.result.losses[0]:.4f} -> {fit.result.losses[-1]:.4f}"
        )
    start = time.time()
    rows = cal.compare({"hand-chosen": s, "learned (MCL)": fits["mcl"].settings, "learned (EKF)": fits["ekf"].settings})
    print(f"compared in {time.time() - start:.0f} s")
    print(cal.format_comparison(rows))
    fields = ("alphas", "pose_sd", "sensor_sd")
    out = {
        "fits": {
            m: {"seconds": f.seconds, "losses": f.result.losses.tolist(), **{k: getattr(f.settings, k) for k in fields}}
            for m, f in fits.items()
        },
        "rows": [r._asdict() for r in rows],
    }
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
