"""Configuration of the lane profile's PDAF tracker (section ``track.pdaf``)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class PdafConfig:
    """Parameters of :class:`edge.track.PdafTracker`; defaults follow Lim et al. §III-B where it gives them."""

    association: str = field(
        default="jpda",
        metadata={"doc": "pdaf: Lim eqs. 17-19 per track; jpda: the same weights shared between tracks whose "
                         "gates hold the same detection (cheap JPDA; identical to pdaf for isolated vehicles, "
                         "keeps ids when vehicles pass close)", "choices": ("pdaf", "jpda")},
    )
    prob_detect: float = field(
        default=0.9, metadata={"doc": "P_D of eqs. 18-19: probability a tracked vehicle gives a detection in a frame",
                               "min": 0.05, "max": 0.999})
    prob_gate: float = field(
        default=0.99, metadata={"doc": "P_G of eq. 17: probability the gate holds the true detection; sets gamma",
                                "min": 0.5, "max": 0.99999})
    init_exclusion_prob: float = field(
        default=0.99999, metadata={"doc": "a detection inside this (wider) chi-square gate of an existing track "
                                          "never seeds a new track: outliers of a tracked vehicle must not spawn "
                                          "a duplicate", "min": 0.5, "max": 0.9999999})
    use_radial_speed: bool = field(
        default=True,
        metadata={"doc": "add the measured radial speed to the measurement (EKF row): separates vehicles at the "
                         "same position with different speeds and makes velocity converge in a few frames"})
    range_sigma_m: float = field(
        default=0.15, metadata={"unit": "m", "doc": "range measurement standard deviation (0.8 m resolution, "
                                                    "sub-bin interpolation)", "min": 0.001, "max": 10.0})
    azimuth_sigma_deg: float = field(
        default=0.5, metadata={"unit": "deg", "doc": "azimuth standard deviation of the Bartlett estimate",
                               "min": 0.001, "max": 20.0})
    radial_speed_sigma_mps: float = field(
        default=0.3, metadata={"unit": "m/s", "doc": "radial speed standard deviation (1.2 m/s resolution, "
                                                     "interpolated)", "min": 0.001, "max": 20.0})
    near_speed_spread_m: float = field(
        default=0.6, metadata={"unit": "m", "doc": "spread along the line of sight of the scatterers whose echo gives "
                                                   "a detection's range and radial speed, for the radial-speed noise "
                                                   "near the radar: the ground radial speed is v_r s / g (slant range "
                                                   "s, ground range g, radar h above the targets), and a scatterer d "
                                                   "farther along sees it change by v h^2 / g^3 d -- for a car at "
                                                   "29 m/s under a 6.5 m mast 3.4 m/s at 6 m out, 0.7 m/s at 10 m, "
                                                   "0.1 at 20 m. That sd is added to radial_speed_sigma_mps (and to a "
                                                   "seed's init_along_speed_sigma_mps) at the track's (seed's) ground "
                                                   "range: a receding car that comes out from under the radar was "
                                                   "seeded with the blurred speed of its first detections and gated "
                                                   "out the next ones for up to 20 frames. highway4-traffic seeds "
                                                   "7016/7022 (10 min), 0 -> 0.6: car Pd 0.9886 -> 0.9896, 0.9881 -> "
                                                   "0.9890, id switches 39 -> 41, 29 -> 31 (0.3: 0.9893, 0.9886, 45, "
                                                   "31; 1.3, a car's length / sqrt(12): 0.9895, 0.9888, 50, 31). The "
                                                   "mounting height comes from the lane pipeline "
                                                   "(PdafTracker.sensor_height_m; the tracker alone: 0, off); 0 = off",
                               "min": 0.0, "max": 20.0})
    extent_sigma_m: float = field(
        default=0.3, metadata={"unit": "m", "doc": "isotropic position noise added for extended vehicles (across "
                                                   "the vehicle: which scatterer gives the peak)", "min": 0.0, "max": 10.0})
    extent_along_sigma_m: float = field(
        default=1.3, metadata={"unit": "m", "doc": "initial spread of a vehicle's detections along its heading "
                                                   "(a 4.5 m car seen as scatterers over its length: 4.5/sqrt(12)); "
                                                   "then learned per track", "min": 0.0, "max": 20.0})
    extent_alpha: float = field(
        default=0.05, metadata={"doc": "smoothing factor of the per-track along-heading spread (and length) estimate",
                                "min": 0.0, "max": 1.0})
    extent_max_sigma_m: float = field(
        default=6.0, metadata={"unit": "m", "doc": "upper bound of the learned along-heading spread (a 20 m "
                                                   "articulated truck: 5.8 m)", "min": 0.1, "max": 50.0})
    extent_near_side_factor: float = field(
        default=0.0, metadata={"doc": "the extent's spread (extent_along_sigma_m, learned) in the state update of a "
                                      "detection nearer the radar than the track's prediction, as a fraction: a track "
                                      "follows the vehicle's near face and the body lies behind it, so a detection in "
                                      "front of the prediction is the face (give or take the sensor's noise), not a "
                                      "scatterer further along (the IMM's mode likelihoods use the same noise); "
                                      "association weights and gates keep the whole spread (1: symmetric, as "
                                      "before). A receding car's track starts on its front while its rear is still "
                                      "under the overpass and then converged on the rear face as 1/n. "
                                      "highway4-traffic seed 11, 1500 frames, receding cars' along-range error "
                                      "at 10-20 / 40-50 / 100-150 m: +1.09 / +0.56 / +0.21 m (RMSE 1.38 / 0.73 / "
                                      "0.39) -> +0.19 / +0.08 / +0.06 m (0.40 / 0.20 / 0.26), approaching cars' "
                                      "+0.18 / +0.11 / +0.11 -> +0.15 / +0.08 / +0.08 m; 0.1: +0.32 / +0.12 / +0.07 m. "
                                      "10-min highway4-traffic, seeds 5, 6, 7005, 7006: position RMSE mean 0.422 / "
                                      "0.428 / 0.404 / 0.393 -> 0.260 / 0.278 / 0.261 / 0.265 m (0-50 m bin 1.01-1.21 "
                                      "-> 0.44-0.66 m), car detection probability 0.9943 / 0.9936 / 0.9909 / 0.9926 "
                                      "-> 0.9944 / 0.9933 / 0.9909 / 0.9919, id switches 36 / 53 / 54 / 46 -> 41 / 48 "
                                      "/ 52 / 37, per-lane counts the same but one more missed on 5 and on 6; crossing "
                                      "(seeds 3, 1, 5, 8) RMSE 0.321 / 0.226 / 0.414 / 0.255 -> 0.233 / 0.216 / 0.250 / "
                                      "0.226 m, lane accuracy 0.966 / 0.994 -> 0.960 / 0.991 on 3 and 1; "
                                      "highway4-misaimed (seeds 1, 31) RMSE 0.893 / 0.644 -> 0.597 / 0.481 m; highway4 "
                                      "(point targets) unchanged. Applies with motion_model = imm and "
                                      "measurement_noise = snr (the defaults)",
                               "min": 0.0, "max": 1.0})
    q_lateral_m2ps3: float = field(
        default=0.5, metadata={"unit": "m^2/s^3", "doc": "white-noise acceleration density across the boresight "
                                                         "(lane changes)", "min": 1e-6, "max": 1000.0})
    q_along_m2ps3: float = field(
        default=2.0, metadata={"unit": "m^2/s^3", "doc": "white-noise acceleration density along the boresight "
                                                         "(braking, stop-and-go)", "min": 1e-6, "max": 1000.0})
    motion_model: str = field(
        default="imm",
        metadata={"doc": "cv: one constant-velocity model (q_lateral_m2ps3, q_along_m2ps3); imm: interacting "
                         "multiple models (edge.track.imm), lane keeping (across-road velocity decaying to zero, "
                         "imm_keep_q_across_m2ps3) and the cv model for manoeuvres, weighed per track by how well "
                         "each explains the detections: far vehicles' lateral position stops wandering with the "
                         "azimuth noise while lane changes are still followed", "choices": ("cv", "imm")},
    )
    imm_keep_q_across_m2ps3: float = field(
        default=0.002, metadata={"unit": "m^2/s^3", "doc": "lane-keeping mode: white-noise acceleration density "
                                                           "across the road (drift within the lane)",
                                 "min": 1e-9, "max": 10.0})
    imm_keep_tau_s: float = field(
        default=1.0, metadata={"unit": "s", "doc": "lane-keeping mode: time constant with which the velocity across "
                                                  "the road decays to zero (the road direction is the mounting yaw "
                                                  "the traffic layer estimates); 0 = no decay", "min": 0.0, "max": 100.0})
    imm_manoeuvre_q_lateral_m2ps3: float = field(
        default=2.0, metadata={"unit": "m^2/s^3", "doc": "manoeuvring mode: white-noise acceleration density "
                                                         "across the boresight (q_lateral_m2ps3 of the cv model; "
                                                         "along: q_along_m2ps3)", "min": 1e-6, "max": 1000.0})
    imm_p_keep_to_manoeuvre: float = field(
        default=0.02, metadata={"doc": "per-frame probability that a lane-keeping vehicle starts a manoeuvre "
                                       "(mean 50 frames = 1.7 s in the mode: a prior, not a rate of lane changes; "
                                       "0.01 left the crossing scenario's lane change too late on 3 of 16 seeds; "
                                       "with measurement_noise = snr 0.01 on 2 of 20, 0.007 on 1 of 20, 0.02 on none)",
                                "min": 1e-6, "max": 0.5})
    imm_far_p_keep_to_manoeuvre: float = field(
        default=0.002, metadata={"doc": "... falling (log-linearly from imm_far_from_m to imm_far_to_m) to this far "
                                        "away: there one detection's lateral noise (0.5-1.5 m) exceeds what a lane "
                                        "change moves in several frames, the mode likelihoods carry no information "
                                        "and the mode probabilities follow the prior; with 0.02 that is 50/50 and a "
                                        "far vehicle's lateral speed wandered by 0.5 m/s with the manoeuvring mode's "
                                        "(highway4 dev seeds: motorcycle 0.19-0.45 m RMSE with 0.02 everywhere); "
                                        "= imm_p_keep_to_manoeuvre: off", "min": 1e-6, "max": 0.5})
    imm_far_from_m: float = field(
        default=150.0, metadata={"unit": "m", "doc": "ground range from which the switching prior falls toward "
                                                     "imm_far_p_keep_to_manoeuvre: lane changes nearer are followed "
                                                     "as before, farther ones later (the crossing scenario's lane "
                                                     "changes start at about 100 m: from 100 m, 1 of 20 seeds "
                                                     "swapped ids; from 150 m none)", "min": 0.0, "max": 1000.0})
    imm_far_to_m: float = field(
        default=220.0, metadata={"unit": "m", "doc": "... reaching it at this ground range", "min": 0.0,
                                 "max": 2000.0})
    imm_p_manoeuvre_to_keep: float = field(
        default=0.02, metadata={"doc": "per-frame probability that a manoeuvre ends (mean 50 frames = 1.7 s; a lane "
                                       "change takes 2-4 s; 0.03 lost a 2 s lane change across a neighbour 1.5 m/s "
                                       "faster in tests/edge/test_pdaf_tracker.py)", "min": 1e-6, "max": 0.5})
    imm_init_keep_prob: float = field(
        default=0.5, metadata={"doc": "probability of the lane-keeping mode for a new track", "min": 0.0, "max": 1.0})
    imm_keep_init_lateral_speed_sigma_mps: float = field(
        default=0.5, metadata={"unit": "m/s", "doc": "initial speed sd across the road of a seed's lane-keeping mode "
                                                     "(the manoeuvring mode starts with init_lateral_speed_sigma_mps): "
                                                     "a vehicle seeded far away, where the azimuth noise is a metre, "
                                                     "does not start drifting across; 0 = as the manoeuvring mode",
                                "min": 0.0, "max": 100.0})
    imm_min_mode_prob: float = field(
        default=1e-3, metadata={"doc": "floor of either mode's probability (a mode can always come back)",
                                "min": 0.0, "max": 0.1})
    lateral_smoother: bool = field(
        default=True,
        metadata={"doc": "publish the across-boresight position from a straight-line filter per track that runs beside "
                         "the motion model, outside the IMM's mixing (edge.track.kalman.lateral_pda_update): a vehicle "
                         "keeping its lane drives a straight line and its lateral position is averaged over every "
                         "detection since it last manoeuvred (the IMM's lane-keeping mode is mixed with the "
                         "manoeuvring mode every frame, which injects ~20x its own lateral process noise); the filter "
                         "restarts from the motion model's estimate when the two disagree (a lane change) and is held "
                         "there during a manoeuvre and on unresolved pairs (lateral_smoother_hold_*). "
                         "Association, gating, ids, the state other stages read and the positions the yaw estimator "
                         "takes stay the motion model's. highway4 motorcycle, dev seeds 1, 3, 5, 8, 21, 44: "
                         "0.186/0.156/0.376/0.313/0.102/0.225 -> 0.044/0.108/0.132/0.090/0.031/0.042 m (car 3 of "
                         "seed 44 0.238 -> 0.223 m); highway4-traffic, 10 min, dev seeds 5 and 6: position RMSE mean "
                         "0.443 -> 0.422 and 0.449 -> 0.428 m (lower in every 50 m bin), car detection probability, "
                         "per-lane counts, false tracks and id switches unchanged, lane accuracy 0.9994 -> 0.9994 "
                         "and 0.9987 -> 0.9990; side-by-side (seeds 3, 8, 21) as with it off; "
                         "crossing lane accuracy (seeds 3, 1, 5, 8) 0.969/1.000/0.966/0.969 -> 0.966/0.994/0.966/0.969, no "
                         "id switch; highway4-misaimed (seeds 1, 31; 120/300 frames) 0.680/0.894, 0.764/0.903 -> 0.687/0.894, "
                         "0.794/0.906; a lane change's largest lateral error 0.35 -> 0.64 m (the line's lag before the "
                         "change is detected)"})
    lateral_smoother_q_m2ps3: float = field(
        default=1e-4, metadata={"unit": "m^2/s^3", "doc": "white-noise acceleration density across the boresight of "
                                                          "the straight-line filter (1e-3 and 1e-5: highway4 alike "
                                                          "within 0.01 m)", "min": 0.0, "max": 10.0})
    lateral_smoother_init_speed_sigma_mps: float = field(
        default=0.03, metadata={"unit": "m/s", "doc": "a new track's straight-line filter starts with its lateral speed "
                                                     "along the road direction (road_yaw_rad) with at most this sd: a "
                                                     "far seed's first, noisy detections must not set its direction "
                                                     "(highway4 worst vehicle per seed, 10 dev seeds: 0.1 -> 3 over "
                                                     "0.15 m, 0.05 -> 2, 0.03 -> 1, car 3 of seed 44, seeded at "
                                                     "260 m); a vehicle whose direction differs (a radar aimed worse "
                                                     "than the road direction is known) is caught by the restart tests",
                                "min": 0.001, "max": 100.0})
    lateral_smoother_hold_manoeuvre_prob: float = field(
        default=0.6, metadata={"doc": "the straight-line filter is held at the motion model's position (and the "
                                      "lane-keeping mode's lateral speed) while the IMM's manoeuvring mode has more "
                                      "than this probability (1: never; ignored with motion_model = cv): the line "
                                      "starts again as the manoeuvre ends. Steady lane keeping stays below it (highway4 "
                                      "seed 1: 0.05-0.47 per vehicle and range, p95; highway4 dev seeds 1, 3, 5, 8, 21, "
                                      "44 the same to 3 decimals as without it). crossing lane accuracy (seeds 3, 1, 5, "
                                      "8) 0.975/0.997/0.966/0.969 -> 0.972/1.000/0.966/0.969 (smoother off: 0.969/"
                                      "1.000/0.966/0.969), position RMSE 0.383/0.258/0.607/0.222 -> 0.372/0.246/0.602/"
                                      "0.228 m (car 1); highway4-misaimed lane accuracy seed 1 (120/300 frames) "
                                      "0.433/0.788 -> 0.542/0.846, seed 31 0.696/0.865 -> 0.764/0.903 (off: 0.680/"
                                      "0.894, 0.764/0.903); a lane change (tests/edge/test_lateral_smoother.py) largest "
                                      "error 0.64 m either way, a second after it 0.024 -> 0.011 m (0.6 keeping the "
                                      "combined lateral speed: 0.128 m)", "min": 0.0, "max": 1.0})
    lateral_smoother_hold_unresolved: bool = field(
        default=True, metadata={"doc": "the straight-line filter is also held at the motion model's position while the "
                                       "detection that carries a track (weight above 0.5) is an unresolved pair "
                                       "(extra['unresolved_pair'] from pipeline.lane's resolver: two cars side by side "
                                       "whose one angle lies between the lanes): the line would sit on one side of the "
                                       "middle, on neither car"})
    lateral_smoother_reset_prob: float = field(
        default=0.99, metadata={"doc": "the straight-line filter restarts from the motion model's estimate when their "
                                       "lateral positions or lateral speeds differ beyond the chi-square (1 dof) "
                                       "quantile of this probability (a Hausman test: the variance of the difference "
                                       "is the motion model's minus the straight line's; 0.9 restarted lane-keeping "
                                       "far vehicles on highway4, 0.99 did not)", "min": 0.5, "max": 0.9999999})
    lateral_smoother_cusum_nats: float = field(
        default=4.0, metadata={"doc": "... or when the detections were explained better by the motion model's "
                                      "predictions than by the straight line's by more than this log-likelihood ratio "
                                      "(nats, Page's CUSUM of edge.track.kalman.lateral_log_likelihood_ratio: a "
                                      "sustained lateral offset; it stays near 0 while the vehicle keeps its lane); "
                                      "the published position moves towards the motion model's as it grows "
                                      "(edge.track.kalman.lateral_blend). A lane change of 3.5 m in 2.5 s at 90-40 m "
                                      "(tests/edge/test_lateral_smoother.py): largest lateral error 0.98 m with the "
                                      "Hausman test alone, 0.64 m with 4, 0.58 m with 3 (the IMM's own 0.35 m); 2 "
                                      "restarted a far lane-keeping motorcycle on highway4",
                               "min": 0.0, "max": 1e6})
    lateral_smoother_min_var_fraction: float = field(
        default=0.1, metadata={"doc": "the Hausman test's variance of the difference is kept at least this fraction of "
                                      "the motion model's own (both are model variances)", "min": 1e-4, "max": 1.0})
    seed_min_radial_speed_mps: float = field(
        default=1.0, metadata={"unit": "m/s", "doc": "detections slower than this (ground radial speed, about 3 sd "
                                                     "of its noise) never seed a "
                                                     "track: guard rails, gantries and poles would otherwise fill the "
                                                     "track table; a vehicle that stops keeps its track (seeding only "
                                                     "applies when the radial speed is measured)", "min": 0.0, "max": 20.0})
    init_along_speed_sigma_mps: float = field(
        default=2.0, metadata={"unit": "m/s", "doc": "initial along-boresight speed sd when the radial speed seeds it",
                               "min": 0.01, "max": 100.0})
    init_lateral_speed_sigma_mps: float = field(
        default=1.5, metadata={"unit": "m/s", "doc": "initial speed sd across the road (the road direction is the "
                                                     "mounting yaw the traffic layer estimates; a mis-aimed radar "
                                                     "sees a few m/s across before it is estimated; the IMM's "
                                                     "lane-keeping mode starts with imm_keep_init_lateral_speed_sigma_mps). "
                                                     "3.0 with measurement_noise = snr let seeds on the strong "
                                                     "in-between detections of two unresolved cars side by side chase "
                                                     "across at 5-9 m/s and swap vehicles (side-by-side seeds 5, 31, "
                                                     "44: 3-6 id switches; 1.5: 0-1). 0.5-1.0 cost the second car of "
                                                     "side-by-side (seeds 8, 31) a tenth of its tracked frames with "
                                                     "the constant noise",
                               "min": 0.01, "max": 100.0})
    init_speed_sigma_mps: float = field(
        default=40.0, metadata={"unit": "m/s", "doc": "initial speed sd when no radial speed is measured",
                                "min": 0.1, "max": 200.0})
    confirm_m: int = field(
        default=5, metadata={"doc": "M of the M-of-N confirmation (5 of 7 frames = 0.2 s: in seeded runs with 3 "
                                    "noise detections per frame it halved the false tracks of 3 of 5)",
                             "min": 1, "max": 32})
    confirm_n: int = field(default=10, metadata={
        "doc": "N of the M-of-N confirmation (frames). A car at 300 m is detected in about half the frames (glint, "
               "12 dB mean SNR): 5 of 7 happens in 0.3 of the windows there, and a tentative track that can no longer "
               "make it is dropped, so cars came into view untracked; 5 of 10 happens in 0.6",
        "min": 1, "max": 32})
    confirmation: str = field(
        default="m_of_n",
        metadata={"doc": "how a tentative track confirms (always also: surely moving, confirm_min_speed_mps, and the "
                         "confirm_block_* rules): m_of_n: confirm_m hits in the last confirm_n frames; score: the "
                         "sequential log-likelihood-ratio track score (edge.track.score, Blackman & Popoli) reaches "
                         "ln((1 - score_true_reject_prob) / score_false_confirm_prob), and a tentative track whose "
                         "score falls to ln(score_true_reject_prob / (1 - score_false_confirm_prob)) is dropped; "
                         "either: whichever comes first (a strong, consistent vehicle confirms in 2-3 frames, a weak "
                         "far one no later than with M-of-N); a tentative track is dropped when M-of-N can no longer be "
                         "reached (keeping it while the score was undecided let the body glint of receding trucks, "
                         "detected in a quarter of the frames, live on until it confirmed a lane beside the truck). Default "
                         "m_of_n: 'either' with seed_min_coherence 0.8 raised car Pd (highway4-traffic, 10 min, seeds "
                         "5/6/4242/2027: 0.985/0.984/0.982/0.975 -> 0.990/0.987/0.985/0.979) but broke the per-lane "
                         "count's +-1 on seeds 5 and 4242 (a lane +2, from new false tracks at the line) and raised "
                         "4242's id switches 48 -> 71 (2027: 91 -> 78)",
                 "choices": ("m_of_n", "score", "either")},
    )
    score_prob_detect: float = field(
        default=0.6, metadata={"doc": "P_D of the score's likelihood ratio: the probability that a vehicle is detected "
                                      "in a frame where tracks are born, at the edges of the coverage (a frame without "
                                      "a validated detection adds ln(1 - P_D P_G)). Measured on highway4-traffic: "
                                      "approaching cars at 280-330 m and receding cars of the outer lane at 12-30 m "
                                      "(outside the antenna's beam) are detected in about half to two thirds of the "
                                      "frames; prob_detect (0.9, the PDAF's) would count each miss as strong evidence "
                                      "against them", "min": 0.05, "max": 0.999})
    score_false_confirm_prob: float = field(
        default=1e-4, metadata={"doc": "alpha of the score's sequential test: probability that a run of false "
                                       "detections seeding a tentative track reaches confirmation",
                                "min": 1e-12, "max": 0.5})
    score_true_reject_prob: float = field(
        default=0.01, metadata={"doc": "beta of the score's sequential test: probability that a vehicle's tentative "
                                       "track is dropped (confirmation = score only)", "min": 1e-9, "max": 0.5})
    score_false_density_m2: float = field(
        default=3e-2, metadata={"unit": "1/m^2", "doc": "density of false moving detections per frame on the ground "
                                                       "(lambda of the score's likelihood ratio). Moving detections "
                                                       "farther than 3 m from every vehicle are rare (0.11 per frame "
                                                       "over the 30 deg x 375 m sector, 3e-6 per m^2; highway4-traffic "
                                                       "seed 7), but false tracks come from detections next to "
                                                       "vehicles (truck body glints, wrong pairings), far denser there: "
                                                       "measured on highway4-traffic seed 6 (6000 frames, M-of-N "
                                                       "expiry): 1e-3 confirmed them (false tracks 7 -> 43 with the "
                                                       "tentative expiry of the score); with M-of-N expiry 1e-2 car Pd "
                                                       "0.982 -> 0.990 and false tracks 7 -> 19, 3e-2 0.985 and 8; with "
                                                       "seed_min_coherence 1e-2 0.989 and 11, 3e-2 0.985 and 4 (false "
                                                       "tracks must not rise: 3e-2)",
                                "min": 1e-12, "max": 10.0})
    score_speed_span_mps: float = field(
        default=139.0, metadata={"unit": "m/s", "doc": "radial-speed span over which false detections spread "
                                                      "uniformly (the pipeline's +-250 km/h): with the radial speed "
                                                      "measured, lambda = score_false_density_m2 / this",
                                 "min": 0.1, "max": 1000.0})
    moving_prob: float = field(
        default=0.9999, metadata={"doc": "a track counts as moving once v' P_v^-1 v exceeds the chi-square (2 dof) "
                                         "quantile of this probability and its speed exceeds confirm_min_speed_mps",
                                  "min": 0.5, "max": 0.9999999})
    confirm_min_speed_mps: float = field(
        default=1.0, metadata={"unit": "m/s", "doc": "a track confirms only once it was surely moving (moving_prob) "
                                                     "at least this fast: static "
                                                     "clutter (guard rail, gantry) is held in unpublished tentative "
                                                     "tracks; a vehicle that stops later stays confirmed",
                               "min": 0.0, "max": 50.0})
    tentative_keep_from_m: float = field(
        default=200.0, metadata={"unit": "m", "doc": "beyond this ground range a tentative track is dropped (M-of-N "
                                                    "confirmation) only once fewer than tentative_keep_min_hits of "
                                                    "its last confirm_n frames hit, instead of as soon as confirm_m "
                                                    "can no longer be reached: an approaching car at 250-330 m is "
                                                    "detected in 0.2-0.7 of the frames, and a track dropped at 4 of "
                                                    "10 was seeded again with an empty history and a fresh velocity. "
                                                    "highway4-traffic, 10 min, with max_azimuth_deg 40: car Pd "
                                                    "seed 6 0.984 -> 0.989 (250-300 m 0.964 -> 0.975; 200 m, 1 hit), "
                                                    "false tracks 1.2 -> 1.0 per minute, counts unchanged, id "
                                                    "switches 51 -> 53; seed 5 0.985 -> 0.989 (250 m, 2 hits), false "
                                                    "tracks 1.5 -> 1.3, id switches 38 -> 41; seed 5, 6000 frames: "
                                                    "200 m and 1 hit 0.9907, 250 m and 2 hits 0.9885; 0 = off",
                               "min": 0.0, "max": 2000.0})
    tentative_keep_min_hits: int = field(
        default=1, metadata={"doc": "hits in the last confirm_n frames that keep a far tentative track "
                                    "(tentative_keep_from_m)", "min": 1, "max": 32})
    delete_after_misses: int = field(
        default=20, metadata={"doc": "consecutive frames without a validated detection before a track is deleted "
                                    "(Lim: tracks survive two or three misses; far vehicles are detected in only "
                                    "half the frames: 20 frames = 0.66 s halved the id switches on highway4-traffic)",
                             "min": 1, "max": 1000})
    max_position_sigma_m: float = field(
        default=8.0, metadata={"unit": "m", "doc": "delete a track whose position sd grows beyond this",
                               "min": 0.1, "max": 1000.0})
    min_range_m: float = field(default=2.0, metadata={"unit": "m", "doc": "tracks live beyond this ground range",
                                                      "min": 0.0, "max": 100.0})
    max_range_m: float = field(default=370.0, metadata={"unit": "m", "doc": "tracks live within this ground range "
                                                                        "(beyond the 300 m design range: an approaching "
                                                                        "vehicle's track is confirmed before it gets there)",
                                                        "min": 1.0, "max": 2000.0})
    max_azimuth_deg: float = field(
        default=40.0, metadata={"unit": "deg", "doc": "tracks are deleted once outside this azimuth. The field of view "
                                                      "is +-15 deg, but a vehicle leaving the overpass in the outer "
                                                      "lane is 25-45 deg off boresight in its first metres and still "
                                                      "seen there (its grating-lobe image is put back in its lane, "
                                                      "pipeline.lane unaliasing): deleted beyond 20 deg its track "
                                                      "started only at 14 m and confirmed inside the field of view "
                                                      "(highway4-traffic seed 11, 6000 frames: receding outer-lane car "
                                                      "Pd at 0-50 m 0.880 at 20 deg, 0.926 at 30, 0.962 at 40; all cars "
                                                      "0.988 -> 0.990; seed 5, 10 min: 0-50 m 0.964 -> 0.981). "
                                                      "An approaching track passing under the deck coasts out as "
                                                      "before (delete_after_misses), now until 40 deg",
                                "min": 1.0, "max": 90.0})
    merge_lateral_m: float = field(
        default=1.5, metadata={"unit": "m", "doc": "two tracks closer than this across and the same-vehicle distance "
                                                   "along (max of merge_along_m, merge_headway_s x speed, "
                                                   "merge_extent_factor x spread) and merge_speed_mps in speed are "
                                                   "one vehicle: the junior is dropped; the same box around a track "
                                                   "keeps its detections from seeding new tracks",
                               "min": 0.0, "max": 20.0})
    merge_lateral_sigmas: float = field(
        default=2.0, metadata={"doc": "for seeding, the lateral same-vehicle distance of raw detections grows "
                                      "with range to this many azimuth standard deviations (r x sigma_az) ...", "min": 0.0, "max": 10.0})
    merge_lateral_max_m: float = field(
        default=3.0, metadata={"unit": "m", "doc": "... but stays below a lane width so vehicles side by side in "
                                                   "adjacent lanes are never merged", "min": 0.0, "max": 20.0})
    merge_along_m: float = field(
        default=5.0, metadata={"unit": "m", "doc": "along-boresight extent of the merge box (a car length)",
                               "min": 0.0, "max": 50.0})
    merge_headway_s: float = field(
        default=0.5, metadata={"unit": "s", "doc": "moving tracks closer along the boresight than this time headway "
                                                  "(centre to centre, within the lateral/speed limits) are one long "
                                                  "vehicle seen at front and rear (0.5 s centre to centre leaves "
                                                  "about 0.3 s bumper to bumper: rare tailgating)",
                               "min": 0.0, "max": 5.0})
    merge_extent_factor: float = field(
        default=3.5, metadata={"doc": "... or closer along than this many learned along-heading spreads (sd) of the "
                                      "track (3.5 ~ sqrt(12): one vehicle length): a long vehicle's own detections", "min": 0.0, "max": 10.0})
    init_merge_along_m: float = field(
        default=10.0, metadata={"unit": "m", "doc": "detections seeding tracks in the same frame within merge_lateral_m "
                                                    "across and this along give one seed (a truck's front and rear)",
                                "min": 0.0, "max": 50.0})
    merge_state_prob: float = field(
        default=0.99, metadata={"doc": "two tracks whose states (position, velocity) are indistinguishable at this "
                                       "chi-square probability are also one vehicle (fresh duplicates from the "
                                       "lateral spread of far detections; settled tracks in adjacent lanes differ)",
                                "min": 0.5, "max": 0.999999})
    merge_speed_mps: float = field(
        default=2.0, metadata={"unit": "m/s", "doc": "speed difference along their common heading below which close tracks are one "
                                                  "vehicle",
                               "min": 0.0, "max": 50.0})
    merge_lateral_speed_mps: float = field(
        default=2.0, metadata={"unit": "m/s", "doc": "... and across-heading speed difference below which they are",
                               "min": 0.0, "max": 50.0})
    merge_persist_frames: int = field(
        default=30, metadata={"doc": "two tracks in each other's same-vehicle box with the same speed along for this "
                                     "many frames are one vehicle whatever their speeds across (a duplicate seeded "
                                     "with a wrong lateral speed drifts onto its vehicle at a few m/s across and "
                                     "counted it twice at the detection line; vehicles crossing each other's path "
                                     "pass through the box in well under a second)", "min": 1, "max": 10000})
    seed_merge_speed_mps: float = field(
        default=5.0, metadata={"unit": "m/s", "doc": "radial-speed difference below which a detection in a track's "
                                                     "same-vehicle box (or next to a stronger seed) does not seed: "
                                                     "wrong pairings on a long truck give ghost detections +-4 m/s "
                                                     "off its speed at its position", "min": 0.0, "max": 50.0})
    seed_min_coherence: float = field(
        default=0.0, metadata={"doc": "a strong detection (seed_coherence_min_snr_db) whose Bartlett peak holds less than "
                                      "this share of its looks' energy (edge.dsp.angle.peak_coherence: 1 for one point "
                                      "source, (N snr + 1) / (N snr + N) for one in noise on N channels) never seeds: "
                                      "the two sides of a receding truck's body in one range bin gave 0.57-0.65 and an "
                                      "angle 3-4 m off, in the approaching lane beside it, while vehicles' own "
                                      "detections at 25-35 m gave 0.89-0.99 (highway4-traffic seed 6); such tracks ran "
                                      "against their lane's direction (false tracks, false wrong-way alarms). Such a "
                                      "detection still updates tracks. 0 = off (the default: see confirmation)", "min": 0.0, "max": 1.0})
    seed_coherence_min_snr_db: float = field(
        default=12.0, metadata={"unit": "dB", "doc": "... applied to detections at least this strong (a point source at "
                                                    "12 dB on 4 channels has 0.95; weak far detections are noisy and "
                                                    "keep seeding)", "min": -20.0, "max": 100.0})
    max_tracks: int = field(default=128, metadata={"doc": "tentative + confirmed tracks held at most", "min": 1,
                                                   "max": 4096})
    max_track_id: int = field(
        default=255, metadata={"doc": "published ids are 1..max_track_id, recycled oldest-released first (fits "
                                      "one CAN byte / Modbus register)", "min": 1, "max": 65535})
    publish_max_misses: int = field(
        default=20, metadata={"doc": "confirmed tracks are published while they missed at most this many frames in a "
                                     "row (they live on, unpublished, until delete_after_misses, to keep their id)",
                              "min": 0, "max": 1000})
    publish_length: bool = field(
        default=True, metadata={"doc": "publish length_m = sqrt(12) x the learned along-heading spread of a moving "
                                       "track (uniform scatterers over the length); meaningful only when the "
                                       "detection chain reports several peaks per vehicle (the lane profile's traffic layer "
                                       "publishes the body's range extent instead)"})
    publish_tentative: bool = field(
        default=False, metadata={"doc": "also publish tentative tracks (confirmed=False, track_id=0)"})
    reanchor_m: float = field(
        default=17.0, metadata={"unit": "m", "doc": "a confirmed track without a detection in its gate moves to a "
                                                    "detection no track validated that lies up to this much nearer "
                                                    "in ground range, within merge_lateral_m across and "
                                                    "reanchor_speed_mps in radial speed: it sat on the body of that "
                                                    "detection's vehicle (a track born on a truck's front as the "
                                                    "truck came out from under the overpass, or on a ghost along "
                                                    "its body) and the near face, the vehicle's reference point, "
                                                    "could not seed because it lies in the track's same-vehicle "
                                                    "box (16.5 m: the longest truck); 0 = off",
                                "min": 0.0, "max": 100.0})
    reanchor_min_m: float = field(
        default=1.0, metadata={"unit": "m", "doc": "... and at least this much nearer: a detection less than a metre "
                                                   "nearer is the track's own vehicle's near face measured badly (an "
                                                   "outlier of the azimuth, outside the gate of a confident track), "
                                                   "not a face the track missed; 0 = any nearer detection",
                               "min": 0.0, "max": 100.0})
    reanchor_receding_only: bool = field(
        default=True, metadata={"doc": "only receding tracks re-anchor (reanchor_m): a receding vehicle comes out "
                                       "from under the overpass front first, so its track can start on its body "
                                       "while its near face (the rear) is still hidden; an approaching vehicle is "
                                       "tracked from afar on its near face (the front), and the unclaimed detection "
                                       "at its speed up to 17 m nearer is the vehicle ahead's pairing ghost "
                                       "(highway4-traffic seed 7018, 6000 frames: all three approaching re-anchors, "
                                       "13.9-16.5 m, jumped from a car onto the car or truck ahead; at 387.98 s car "
                                       "105's track jumped 16.5 m onto car 104 at 84 m, crossed the line with it and "
                                       "held car 105's next track tentative: lane 0 -1; seed 7007: car 4's track "
                                       "jumped 16 m at 70 m and crossed 0.7 s early, lane 0 +1). Ten minutes each, "
                                       "seeds 5, 7007, 7012, 7015, 7016, 7018, all-lane |count error| 12 -> 6, car "
                                       "detection probability up on every seed (7016 0.9866 -> 0.9894), id switches "
                                       "308 -> 219, RMSE mean down 0.002-0.014 m; highway4 seeds 7001-7040 and the "
                                       "golden fixtures unchanged"})
    reanchor_speed_mps: float = field(
        default=1.0, metadata={"unit": "m/s", "doc": "radial-speed difference within which a re-anchoring "
                                                     "detection is the track's own vehicle", "min": 0.0, "max": 20.0})
    confirm_block_along_m: float = field(
        default=17.0, metadata={"unit": "m", "doc": "a tentative track is not confirmed while a confirmed track lies "
                                                    "within merge_lateral_m across and this far along with a velocity "
                                                    "within merge_speed_mps: the same long vehicle (16.5 m truck) "
                                                    "seeded twice; it stays tentative until the duplicate check "
                                                    "drops it or it moves clear (a follower this close at the same "
                                                    "speed, 0.6 s headway at 100 km/h, waits too); 0 = off",
                                "min": 0.0, "max": 100.0})
    confirm_block_lateral_m: float = field(
        default=3.5, metadata={"unit": "m", "doc": "... and not while a confirmed track lies within this across "
                                                   "(and confirm_block_along_m along) whose speed along is within "
                                                   "confirm_block_speed_mps: the two sides of a truck at one range "
                                                   "glint its body's echo up to a lane width beside it, at exactly "
                                                   "its speed, behind its near face (a vehicle in the next lane "
                                                   "that far behind waits until their speeds differ)",
                                "min": 0.0, "max": 20.0})
    confirm_block_speed_mps: float = field(
        default=1.0, metadata={"unit": "m/s", "doc": "speed difference along of confirm_block_lateral_m (a young "
                                                     "track's speed is good to a few tenths)",
                               "min": 0.0, "max": 10.0})
    confirm_block_behind_m: float = field(
        default=2.0, metadata={"unit": "m", "doc": "... counted only for tentative tracks more than this farther from "
                                                   "the radar than the confirmed one (body glint comes from behind the "
                                                   "near face; two vehicles side by side at one range both confirm)",
                               "min": 0.0, "max": 50.0})
    confirm_block_max_range_m: float = field(
        default=100.0, metadata={"unit": "m", "doc": "... and only for confirmed tracks nearer than this: farther "
                                                     "out the azimuth noise is comparable with the glint offset and the "
                                                     "glint joins the truck's own track, while a car in the next lane "
                                                     "at the truck's speed must not wait",
                                 "min": 0.0, "max": 1000.0})
    measurement_noise: str = field(
        default="snr",
        metadata={"doc": "constant: one R per track from range_sigma_m, azimuth_sigma_deg and extent_sigma_m at its "
                         "prediction (Lim); snr: one R per detection from its SNR, sigma^2 = sigma0^2 / SNR + floor^2 "
                         "for azimuth and range (Cramer-Rao form, snr_* fields, fitted to the simulated SIMO board), "
                         "so strong far detections are trusted and weak ones are not; the PDAF update then uses one "
                         "gain per detection (edge.track.pdaf.combined_update_each)", "choices": ("constant", "snr")},
    )
    seed_exclusion_noise: str = field(
        default="constant",
        metadata={"doc": "with measurement_noise = snr, the noise model of the exclusion gate that keeps a tracked "
                         "vehicle's detections from seeding (init_exclusion_prob): constant (range_sigma_m, "
                         "azimuth_sigma_deg: two vehicles side by side, unresolved in angle, give strong detections "
                         "between them that the SNR noise puts outside the gate; as seeds they became tracks that "
                         "swapped vehicles) or snr", "choices": ("constant", "snr")},
    )
    snr_azimuth_sigma_deg: float = field(
        default=0.88, metadata={"unit": "deg", "doc": "measurement_noise = snr: azimuth sd at 0 dB SNR "
                                                      "(sigma_az = this / sqrt(SNR)). Fitted on highway4 dev seeds 1, 2, "
                                                      "3, 5, 8 (6853 detections against the true position, 20-300 m, "
                                                      "4-40 dB): 0.88; the Cramer-Rao bound of the 4-channel array "
                                                      "(d = 1.5 lambda) with the 4 segments as looks is 0.96. "
                                                      "radar-edge fit-noise reproduces the fit (0.85 with this "
                                                      "tracker's aided pairings)",
                                "min": 0.001, "max": 20.0})
    snr_azimuth_floor_deg: float = field(
        default=0.03, metadata={"unit": "deg", "doc": "... plus this azimuth sd in quadrature (calibration, glint of "
                                                      "a vehicle's scatterers; fitted: 0.026)", "min": 0.0, "max": 5.0})
    snr_range_sigma_m: float = field(
        default=0.165, metadata={"unit": "m", "doc": "measurement_noise = snr: range sd at 0 dB SNR (sub-bin "
                                                     "interpolation of the beat frequencies; fitted as the azimuth: "
                                                     "0.165)", "min": 0.001, "max": 10.0})
    snr_range_floor_m: float = field(
        default=0.015, metadata={"unit": "m", "doc": "... plus this range sd in quadrature (fitted: 0.015)",
                                 "min": 0.0, "max": 5.0})
    snr_extent_sigma_m: float = field(
        default=0.47, metadata={"unit": "m", "doc": "measurement_noise = snr: isotropic position sd added to every "
                                                    "detection (extent_sigma_m of the constant model): which of an "
                                                    "extended vehicle's scatterers gives the peak. Fitted with the "
                                                    "azimuth law fixed on highway4-traffic seed 5 (17316 detections "
                                                    "of hw_sim.vehicles bodies against their near-face point): 0.47 "
                                                    "(a 1.8 m wide car, uniform: 0.52); highway4's point-like targets "
                                                    "show < 0.01, but a floor that small made confident tracks lose "
                                                    "real vehicles' detections from their gates (crossing: id swaps). "
                                                    "Along the heading the learned spread of the vehicle is added",
                                "min": 0.0, "max": 10.0})
    snr_min_db: float = field(
        default=6.0, metadata={"unit": "dB", "doc": "a detection's SNR is taken as at least this in the law (a "
                                                    "detection without a finite SNR counts as this): below, the "
                                                    "measured error saturates (4.5 dB at 240 m: 1.5 m sd, the law "
                                                    "2.2 m)", "min": -20.0, "max": 60.0})
    snr_max_db: float = field(
        default=45.0, metadata={"unit": "dB", "doc": "... and at most this (the floors dominate beyond)",
                                "min": -20.0, "max": 100.0})
