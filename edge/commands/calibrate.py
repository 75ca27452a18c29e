"""``radar-edge calibrate``: derive the surveillance threshold th_RD from frames of an empty scene, or (``--rcs``) the
board's RCS calibration constant C from frames of a corner reflector."""

from __future__ import annotations

import argparse
import sys

from edge.commands.common import add_config_arguments, config_from_args, emit_json

NAME = "calibrate"
HELP = ("derive the surveillance threshold th_RD (empty scene), the RCS constant C (--rcs: a corner reflector) or "
        "the TX power level that keeps the ADC off its rails (--headroom)")
DESCRIPTION = """\
Tavanti et al. set th_RD from radar frames taken with no moving target in view: every frame goes
through the IIR clutter/leakage canceller and the range-Doppler map, the largest map amplitude of
each frame is kept, and the first estimate of th_RD is the mean of these maxima. That estimate is
"often too low" (the paper then corrects it by hand), so this command adds a documented margin:

    th_RD = mean(maxima) + K * std(maxima)      (K = --margin-std, default 3)

With K = 3 only a fraction of a percent of empty frames reach the threshold anywhere on the map, and
a single bin over threshold never makes a DBSCAN cluster (M points are needed). The maps use the
canceller and window settings of the configuration (pipeline.surveillance.k_c, k_sf, n_range_fft,
n_doppler_fft). Point the source at the installed board with nothing moving in its beam (people,
vehicles, swaying branches) for at least a few dozen frames; the default is the simulated site.

With --rcs, the board's RCS calibration constant C instead (edge.classify.calibration): the
classifier's RCS feature (eq. 17) is referred through C to the board the reference set was built
on, so a board whose TX power, gain, radome or mounting differ by a few dB still reads a car's RCS
as a car's. Procedure:
  1. a triangular trihedral corner reflector of inner edge a (sigma = 4 pi a^4 / 3 lambda^2: 2.69 m^2
     for a = 0.10 m at 24 GHz; --reflector-edge-m, or --reflector-rcs-m2 for another reflector) on a
     non-metallic stand, its aperture facing the radar, on boresight (azimuth and elevation) at a
     tape-measured range of 3-10 m (--range-m; its uncertainty --range-sd-m), nothing else that
     reflects within 1 m of that range, nothing moving in the beam;
  2. radar-edge calibrate --rcs --source d2g:///dev/ttyACM0 --range-m 5 --reflector-edge-m 0.1
     measures the reflector's echo (the chirps averaged, the strongest static tone within
     --window-m of the range) over --frames frames and computes
         C = 10 log10(A^2 R^4 / sigma)   (A: tone amplitude in counts, IF high-pass compensated)
     with its uncertainty (the frames' spread and the range's 40 log10 term, in quadrature);
     a measurement on which the ADC clips is refused;
  3. store the printed settings in the installation's configuration ([classify.features]
     rcs_calibration_db, rcs_calibration_sd_db, rcs_calibration_source = "measured");
     `radar-edge doctor` shows them. Without a measurement the datasheet value stands
     (rcs_calibration_source = "datasheet", several dB of unit spread).

With --headroom, the first step on site with a Distance2Go: its TX->RX leakage uses about two thirds
of the 12-bit ADC's full scale on a nominal unit, so a unit a few dB hotter clips on it, and every
echo with it (C cannot be measured on a clipping board). With the scene empty, the board's TX power
levels are tried from the highest down (the source URL's tx_power option), --frames frames each; the
highest level at which no sample clips and the largest |I| or |Q| stays within --max-full-scale of
full scale (default 0.8: 2 dB for the leakage's drift and the echoes on top) is printed as the
source URL to install. Measure C (--rcs) at that level: C includes the TX power."""
EPILOG = """\
examples:
  radar-edge calibrate                                   # simulated empty site (sim://d2g, empty-d2g)
  radar-edge calibrate --source d2g:///dev/ttyACM0 --frames 300 --json th.json
  radar-edge calibrate --frames 100 --margin-std 2 --set pipeline.surveillance.k_c=0.3

  radar-edge calibrate --rcs                             # simulated reflector (sim://d2g, reflector-d2g)
  radar-edge calibrate --rcs --source d2g:///dev/ttyACM0 --range-m 6 --reflector-edge-m 0.15 --json c.json

  radar-edge calibrate --headroom                        # simulated empty site at each TX power level
  radar-edge calibrate --headroom --source d2g:///dev/ttyACM0 --frames 20

then use the result:  radar-edge run --set pipeline.surveillance.th_rd=VALUE   (or [pipeline.surveillance]
th_rd = VALUE in the configuration file)
"""

DEFAULT_SOURCE = "sim://d2g?scenario=empty-d2g&realtime=0"
DEFAULT_RCS_SOURCE = "sim://d2g?scenario=reflector-d2g&realtime=0"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", default=None, help=f"radar source URL with an empty scene (default: {DEFAULT_SOURCE}; "
                   f"with --rcs the reflector in view, default {DEFAULT_RCS_SOURCE})")
    p.add_argument("--frames", type=int, default=50, help="frames to use (default: 50 = 10 s)")
    p.add_argument("--rcs", action="store_true", help="measure the RCS calibration constant C from a corner reflector "
                   "(procedure above) instead of th_RD")
    p.add_argument("--headroom", action="store_true", help="pick the Distance2Go's TX power level: the highest at which "
                   "the ADC does not clip on an empty scene (procedure above)")
    p.add_argument("--max-full-scale", type=float, default=0.8,
                   help="--headroom: largest |I| or |Q| allowed, as a fraction of the ADC's full scale (default 0.8)")
    p.add_argument("--range-m", type=float, default=5.0, help="--rcs: the reflector's range, tape-measured (m; default 5)")
    p.add_argument("--range-sd-m", type=float, default=0.05, help="--rcs: uncertainty (1 sd) of --range-m (m; default 0.05)")
    p.add_argument("--reflector-edge-m", type=float, default=0.10,
                   help="--rcs: inner edge a of the triangular trihedral (m; default 0.10: 2.69 m^2 at 24 GHz)")
    p.add_argument("--reflector-rcs-m2", type=float, default=None,
                   help="--rcs: the reflector's RCS (m^2) instead of the trihedral's from --reflector-edge-m")
    p.add_argument("--window-m", type=float, default=0.75,
                   help="--rcs: the reflector's echo is the strongest within this of --range-m (m; default 0.75)")
    p.add_argument("--skip", type=int, default=0, help="frames to discard first (warm-up)")
    p.add_argument("--margin-std", type=float, default=3.0, help="K in th_RD = mean + K * std of the per-frame maxima (default: 3)")
    p.add_argument("--json", metavar="OUT", help="also write the statistics and the result here")
    add_config_arguments(p)


def calibrate_threshold(frames, processor, *, margin_std: float = 3.0) -> dict:
    """Per-frame maxima of the canceller's range-Doppler maps -> th_RD statistics.

    ``frames``: iterable of :class:`~hal.frame.RawFrame`; ``processor`` a
    :class:`~edge.dsp.range_doppler.RangeDopplerProcessor`. Returns a dict with ``th_rd``,
    ``mean_of_maxima`` (the paper's first estimate), ``std_of_maxima``, percentiles and ``frames``.
    """
    import numpy as np

    maxima = []
    where = []
    for f in frames:
        m = processor.process(f.iq()).amplitude
        k = int(np.argmax(m))
        maxima.append(float(m.flat[k]))
        where.append(float(processor.range_m[k // m.shape[1]]))
    if len(maxima) < 2:
        raise ValueError("calibration needs at least two frames")
    mx = np.asarray(maxima)
    mean, std = float(mx.mean()), float(mx.std(ddof=1))
    th = mean + margin_std * std
    return {
        "th_rd": th,
        "mean_of_maxima": mean,
        "std_of_maxima": std,
        "margin_std": margin_std,
        "max_of_maxima": float(mx.max()),
        "p50_of_maxima": float(np.percentile(mx, 50)),
        "p99_of_maxima": float(np.percentile(mx, 99)),
        "fraction_of_frames_over_th": float(np.mean(mx >= th)),
        "median_range_of_maximum_m": float(np.median(where)),
        "frames": int(mx.size),
    }


def run(args: argparse.Namespace) -> int:
    import itertools

    from edge.dsp.range_doppler import RangeDopplerProcessor
    from hal import open_radar

    if args.frames < 2:
        raise ValueError("--frames must be at least 2")
    if args.rcs and args.headroom:
        raise ValueError("--rcs and --headroom are two steps: pick the TX power level first, then measure C at it")
    if args.rcs:
        return run_rcs(args)
    if args.headroom:
        return run_headroom(args)
    args.source = args.source or DEFAULT_SOURCE
    cfg = config_from_args(args)
    sc = cfg.section("pipeline.surveillance")
    with open_radar(args.source) as src:
        proc = RangeDopplerProcessor(
            src.frontend, k_c=sc.k_c, k_sf=sc.k_sf, n_range_fft=sc.n_range_fft, n_doppler_fft=sc.n_doppler_fft
        )
        frames = itertools.islice(iter(src), args.skip, args.skip + args.frames)
        res = calibrate_threshold(frames, proc, margin_std=args.margin_std)
    res["source"] = args.source
    print(
        f"{res['frames']} frames: per-frame maximum mean {res['mean_of_maxima']:.3f}, std {res['std_of_maxima']:.3f}, "
        f"max {res['max_of_maxima']:.3f} (median at {res['median_range_of_maximum_m']:.1f} m)"
    )
    print(f"th_RD = {res['mean_of_maxima']:.3f} + {args.margin_std:g} x {res['std_of_maxima']:.3f} = {res['th_rd']:.3f}"
          f"   (current: {sc.th_rd:g})")
    print(f"use: --set pipeline.surveillance.th_rd={res['th_rd']:.3f}")
    if args.json:
        emit_json(res, args.json)
    sys.stdout.flush()
    return 0


def run_rcs(args: argparse.Namespace) -> int:
    """``--rcs``: C from frames of a corner reflector (edge.classify.calibration.measure_reflector), printed with
    the settings that store it."""
    import itertools

    from edge.classify.calibration import DATASHEET_C_DB, measure_reflector, trihedral_rcs_m2
    from hal import open_radar

    source = args.source or DEFAULT_RCS_SOURCE
    cfg = config_from_args(args)
    fc = cfg.section("classify.features")
    sc = cfg.section("pipeline.surveillance")
    with open_radar(source) as src:
        fe = src.frontend
        sigma = args.reflector_rcs_m2 or trihedral_rcs_m2(args.reflector_edge_m, fe.waveform.wavelength_m)
        frames = itertools.islice(iter(src), args.skip, args.skip + args.frames)
        res = measure_reflector(frames, fe, rcs_m2=sigma, range_m=args.range_m, range_sd_m=args.range_sd_m,
                                if_corner_hz=fc.if_corner_hz, window_m=args.window_m, k_sf=sc.k_sf)
    res["source"] = source
    res["datasheet_c_db"] = DATASHEET_C_DB
    res["set"] = [f"classify.features.rcs_calibration_db={res['c_db']:.2f}",
                  f"classify.features.rcs_calibration_sd_db={res['c_sd_db']:.2f}",
                  "classify.features.rcs_calibration_source=measured"]
    print(f"{res['frames']} frames: reflector {sigma:.3g} m^2 at {args.range_m:g} m (echo peak at "
          f"{res['measured_peak_range_m']:.2f} m), amplitude {res['amplitude_counts']:.1f} counts rms")
    print(f"C = {res['c_db']:.2f} +- {res['c_sd_db']:.2f} dB (frames {res['c_sd_frames_db']:.2f}, range "
          f"{res['c_sd_range_db']:.2f}); datasheet {DATASHEET_C_DB:.2f} dB: this board reads "
          f"{res['c_db'] - DATASHEET_C_DB:+.2f} dB   (current: {fc.rcs_calibration_db:.2f}, {fc.rcs_calibration_source})")
    print("store in the configuration's [classify.features]:  " + "  ".join(f"--set {x}" for x in res["set"]))
    if args.json:
        emit_json(res, args.json)
    sys.stdout.flush()
    return 0


def with_tx_power(url: str, level: int) -> str:
    """``url`` with its ``tx_power`` option set to ``level`` (any other option kept as written)."""
    base, _, query = url.partition("?")
    opts = [o for o in query.split("&") if o and o.split("=", 1)[0] != "tx_power"]
    return f"{base}?{'&'.join(opts + [f'tx_power={int(level)}'])}"


def adc_headroom(frames) -> dict:
    """Over ``frames`` (:class:`~edge.types.RawFrame`): the largest |I| or |Q| in counts, its fraction of the ADC's
    full scale, and the fraction of the samples at full scale (clipped)."""
    peak = clipped = total = n = 0
    full = None
    for f in frames:
        c, t = f.clipped_samples()
        clipped, total, n = clipped + c, total + t, n + 1
        p, full = f.peak_counts()
        peak = max(peak, p)
    if n == 0:
        raise ValueError("no frames were read")
    return {"frames": n, "peak_counts": peak, "full_scale_counts": full, "peak_fraction": peak / full,
            "clipped_fraction": clipped / total}


def pick_tx_power(measure, max_level: int, max_full_scale: float) -> dict:
    """The highest TX power level, from ``max_level`` down to 0, whose :func:`adc_headroom` (``measure(level)``)
    shows no clipped sample and a peak within ``max_full_scale`` of full scale; ``level`` None when none does."""
    tried = []
    for level in range(int(max_level), -1, -1):
        h = dict(measure(level), level=level)
        tried.append(h)
        if h["clipped_fraction"] == 0.0 and h["peak_fraction"] <= max_full_scale:
            return {"level": level, "max_level": int(max_level), "max_full_scale": max_full_scale, "levels": tried}
    return {"level": None, "max_level": int(max_level), "max_full_scale": max_full_scale, "levels": tried}


def run_headroom(args: argparse.Namespace) -> int:
    """``--headroom``: the TX power level to install (:func:`pick_tx_power` over the source at each level)."""
    import itertools

    from hal import open_radar

    source = args.source or DEFAULT_SOURCE
    if not 0.0 < args.max_full_scale <= 1.0:
        raise ValueError("--max-full-scale must be in (0, 1]")
    with open_radar(source) as src:
        max_level = getattr(src, "max_tx_power", None)
    if max_level is None:
        print(f"radar-edge calibrate: {source} has no TX power setting (--headroom is for the Distance2Go)",
              file=sys.stderr)
        return 2

    def measure(level: int) -> dict:
        with open_radar(with_tx_power(source, level)) as src:
            h = adc_headroom(itertools.islice(iter(src), args.skip, args.skip + args.frames))
        print(f"TX power level {level}: peak {h['peak_counts']} of {h['full_scale_counts']} counts "
              f"({h['peak_fraction']:.0%}), clipped {h['clipped_fraction']:.2%} of the samples")
        return h

    res = pick_tx_power(measure, max_level, args.max_full_scale)
    res["source"] = source
    if res["level"] is None:
        print(f"no TX power level keeps the ADC within {args.max_full_scale:.0%} of full scale: the receive chain "
              "itself is saturated (check the radome and what stands in front of the antennas)")
        code = 1
    else:
        res["url"] = with_tx_power(source, res["level"])
        print(f"install TX power level {res['level']} of {max_level}: source.url = \"{res['url']}\"")
        print(f"then measure C at that level: radar-edge calibrate --rcs --source \"{res['url']}\" ...")
        code = 0
    if args.json:
        emit_json(res, args.json)
    sys.stdout.flush()
    return code
