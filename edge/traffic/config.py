"""Configuration of the traffic layer (section ``traffic``): lanes, mounting yaw, statistics, events."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class TrafficConfig:
    """Parameters of :class:`edge.traffic.TrafficMonitor`. Lateral offsets are in the road frame, relative
    to the radar's foot (right +); along-road distances from the radar's foot."""

    lane_mode: str = field(
        default="configured",
        metadata={"doc": "configured: lanes from lane_centers_m/lane_widths_m/lane_directions; learned: lanes "
                         "from the lateral distribution of confirmed tracks (side-fire style auto-configuration)",
                  "choices": ("configured", "learned")})
    lane_centers_m: tuple[float, ...] = field(
        default=(-5.25, -1.75, 1.75, 5.25),
        metadata={"unit": "m", "doc": "lane centre offsets across the road (Lim Fig. 11: four 3.5 m lanes); lane "
                                      "index = position in this list"})
    lane_widths_m: tuple[float, ...] = field(
        default=(3.5,), metadata={"unit": "m", "doc": "lane widths (one value = every lane)", "min": 0.5, "max": 20.0})
    lane_directions: tuple[str, ...] = field(
        default=("toward", "toward", "away", "away"),
        metadata={"doc": "direction of travel per lane: toward or away from the radar"})
    default_lane_width_m: float = field(
        default=3.5, metadata={"unit": "m", "doc": "width of a learned lane when only one lane is seen",
                               "min": 0.5, "max": 20.0})
    mounting_yaw_deg: float = field(
        default=0.0, metadata={"unit": "deg", "doc": "radar yaw against the road axis (clockwise, as hw_sim "
                                                     "RadarPose.yaw_deg); used until estimated", "min": -45.0, "max": 45.0})
    mounting_yaw_sigma_deg: float = field(
        default=1.0, metadata={"unit": "deg", "doc": "sd of the configured mounting yaw: until the yaw is estimated, "
                                                     "lane assignment at range r is uncertain by r x this across the "
                                                     "road (the wrong-way gate; ignored with estimate_yaw off); the "
                                                     "start-up alignment to configured lanes searches 5 sd about it",
                               "min": 0.0, "max": 45.0})
    estimate_yaw: bool = field(
        default=True, metadata={"doc": "estimate the mounting yaw from the direction of straight confirmed tracks"})
    yaw_min_tracks: int = field(
        default=5, metadata={"doc": "straight tracks needed before the yaw estimate is used (ended ones; at start-up "
                                    "running ones count too, see yaw_live_min_length_m; with configured lanes, the "
                                    "alignment of this many tracks in lanes comes first, lanes.align_yaw, until the "
                                    "ended tracks' directions are at least as certain)", "min": 1, "max": 10000})
    yaw_window_tracks: int = field(
        default=200, metadata={"doc": "most recent straight tracks the yaw is the median of", "min": 1, "max": 100000})
    yaw_min_track_length_m: float = field(
        default=40.0, metadata={"unit": "m", "doc": "a track must cover this distance to vote for the yaw",
                                "min": 1.0, "max": 1000.0})
    yaw_live_min_length_m: float = field(
        default=20.0, metadata={"unit": "m", "doc": "at start-up (fewer than yaw_min_tracks ended tracks), running "
                                                    "tracks vote once they covered this distance (with configured "
                                                    "lanes only while too few tracks are in lanes to align them)",
                                "min": 1.0, "max": 1000.0})
    yaw_max_lateral_sd_m: float = field(
        default=0.8, metadata={"unit": "m", "doc": "a track whose positions scatter more than this across its "
                                                   "fitted line (a lane change) does not vote", "min": 0.01, "max": 20.0})
    learn_min_samples: int = field(
        default=2000, metadata={"doc": "track positions (frames x tracks) before lanes are learned",
                                "min": 10, "max": 10_000_000})
    learn_buffer_samples: int = field(
        default=50000, metadata={"doc": "ring buffer of track positions lanes are learned from (bounded memory)",
                                 "min": 100, "max": 10_000_000})
    learn_min_range_m: float = field(
        default=10.0, metadata={"unit": "m", "doc": "positions nearer than this do not teach lanes", "min": 0.0,
                                "max": 1000.0})
    learn_max_range_m: float = field(
        default=150.0, metadata={"unit": "m", "doc": "positions further than this do not teach lanes (lateral error "
                                                     "grows with range x azimuth error)", "min": 1.0, "max": 1000.0})
    learn_bin_m: float = field(default=0.1, metadata={"unit": "m", "doc": "lateral histogram bin", "min": 0.01,
                                                      "max": 2.0})
    learn_smooth_m: float = field(
        default=0.4, metadata={"unit": "m", "doc": "Gaussian smoothing sd of the lateral histogram", "min": 0.0,
                               "max": 5.0})
    learn_min_separation_m: float = field(
        default=2.5, metadata={"unit": "m", "doc": "learned lane centres are at least this far apart", "min": 0.5,
                               "max": 20.0})
    learn_peak_fraction: float = field(
        default=0.1, metadata={"doc": "a histogram peak below this fraction of the highest is not a lane",
                               "min": 0.0, "max": 1.0})
    learn_lateral_extent_m: float = field(
        default=30.0, metadata={"unit": "m", "doc": "lateral half-width searched for lanes", "min": 1.0, "max": 200.0})
    relearn_every_s: float = field(
        default=60.0, metadata={"unit": "s", "doc": "re-learn lanes (and use the newest yaw) this often",
                                "min": 0.1, "max": 86400.0})
    calibration_file: str = field(
        default="", metadata={"doc": "keep the self-calibration (estimated mounting yaw, learned lanes) in this JSON "
                                     "file across restarts, e.g. /var/lib/radar-edge/traffic-calibration.json; "
                                     "empty = start uncalibrated every time (see edge.traffic.calibration)"})
    calibration_save_every_s: float = field(
        default=60.0, metadata={"unit": "s", "doc": "save the calibration this often (and at stop)",
                                "min": 1.0, "max": 86400.0})
    calibration_moved_deg: float = field(
        default=1.0, metadata={"unit": "deg", "doc": "a fresh yaw estimate (from yaw_min_tracks ended tracks) this "
                                                     "far from the saved one means the radar was re-aimed: the saved "
                                                     "calibration is dropped", "min": 0.1, "max": 45.0})
    interval_s: float = field(
        default=60.0, metadata={"unit": "s", "doc": "statistics interval", "min": 1.0, "max": 86400.0})
    detection_line_m: float = field(
        default=50.0, metadata={"unit": "m", "doc": "along-road distance of the virtual detection line (volume, "
                                                    "speeds, headway are taken where tracks cross it)",
                                "min": 0.0, "max": 1000.0})
    presence_zone_m: float = field(
        default=5.0, metadata={"unit": "m", "doc": "length of the presence zone centred on the detection line "
                                                   "(occupancy = time a vehicle overlaps it)", "min": 0.1, "max": 100.0})
    default_vehicle_length_m: float = field(
        default=4.5, metadata={"unit": "m", "doc": "length a vehicle is taken to have in the occupancy while its own "
                                                   "is not measured (the gap is then n/a)",
                               "min": 0.5, "max": 30.0})
    length_range_m: tuple[float, ...] = field(
        default=(20.0, 150.0),
        metadata={"unit": "m", "doc": "slant ranges (nearest, farthest) where a track's body extent is measured: nearer, "
                                      "the body smears over many bins; farther, its far end drowns in the noise",
                  "min": 0.0, "max": 1000.0})
    length_min_frames: int = field(
        default=10, metadata={"doc": "frames with a detection in length_range_m before a track's length is measured "
                                     "(until then its length and class are n/a)", "min": 1, "max": 100000})
    length_outliers: int = field(
        default=2, metadata={"doc": "a track's length is its (this + 1)-th largest body extent: this many larger ones are "
                                    "taken for another vehicle or a glint behind it", "min": 0, "max": 100})
    length_min_m: float = field(
        default=1.5, metadata={"unit": "m", "doc": "range resolution of the body extent (two 0.75 m bins): a vehicle "
                                                   "whose measured length is below it is shorter than can be measured "
                                                   "(length n/a, the shortest length class)", "min": 0.0, "max": 10.0})
    length_class_edges_m: tuple[float, ...] = field(
        default=(3.05, 5.79),
        metadata={"unit": "m", "doc": "length class boundaries (10 ft and 19 ft: the Maine DOT length bins for FHWA "
                                      "Scheme F, classes 1 / 2-3 / 4-13; a track with a class from a classifier counts "
                                      "under that class instead)", "min": 0.1, "max": 50.0})
    length_class_names: tuple[str, ...] = field(
        default=("motorcycle", "car", "truck"),
        metadata={"doc": "names of the length classes (one more than the edges; the Modbus and CAN class counts "
                         "group motorcycle, car, truck and bus, anything else counts as other)"})
    count_late_max_m: float = field(
        default=30.0, metadata={"unit": "m", "doc": "a confirmed track first seen up to this far past the detection "
                                                    "line, in its lane's direction, is counted at its crossing time "
                                                    "extrapolated back, unless count_late_match_* finds that crossing "
                                                    "counted; 0 = off",
                                "min": 0.0, "max": 300.0})
    count_late_receding_max_m: float = field(
        default=60.0, metadata={"unit": "m", "doc": "the same up to this far past the line for a receding track "
                                                    "count_late_far_margin_m inside its lane (a car masked by a truck "
                                                    "overtaking it); 0 = count_late_max_m for both directions",
                                "min": 0.0, "max": 300.0})
    count_late_far_margin_m: float = field(
        default=0.5, metadata={"unit": "m", "doc": "... inside its lane's nearer edge by at least this much (the "
                                                   "ghost of a neighbour sits by the lane boundary)",
                               "min": 0.0, "max": 10.0})
    count_late_match_s: float = field(
        default=1.0, metadata={"unit": "s", "doc": "a late crossing within this of a counted one in the lane ...",
                               "min": 0.0, "max": 10.0})
    count_late_match_speed_mps: float = field(
        default=3.0, metadata={"unit": "m/s", "doc": "... at a speed within this is that vehicle again",
                               "min": 0.0, "max": 50.0})
    count_once_per_track: bool = field(
        default=True, metadata={"doc": "a track is counted at the detection line once, also if it moves back behind "
                                       "the line and crosses it again"})
    wrong_way_min_speed_mps: float = field(
        default=3.0, metadata={"unit": "m/s", "doc": "against the lane direction at least this fast is wrong-way",
                               "min": 0.1, "max": 100.0})
    wrong_way_min_frames: int = field(
        default=15, metadata={"doc": "frames with a detection in a row against the lane direction before the "
                                     "event (0.5 s; coasting frames neither count nor reset)",
                              "min": 1, "max": 10000})
    wrong_way_lane_sigmas: float = field(
        default=2.0, metadata={"doc": "a frame counts towards wrong_way only while the track is this many sds inside "
                                      "its lane: distance to the lane's nearer edge over range x the yaw's and the "
                                      "tracks' azimuth sd (a failing frame neither counts nor resets)",
                               "min": 0.0, "max": 10.0})
    wrong_way_azimuth_sigma_deg: float = field(
        default=0.1, metadata={"unit": "deg", "doc": "the tracks' azimuth sd in the wrong_way_lane_sigmas gate, added "
                                                     "in quadrature to the yaw's; 0 = the yaw's only",
                               "min": 0.0, "max": 10.0})
    wrong_way_same_driver_m: float = field(
        default=20.0, metadata={"unit": "m", "doc": "a track qualifying for wrong_way within this along the road of a "
                                                    "track that raised it and still runs ...",
                                "min": 0.0, "max": 200.0})
    wrong_way_same_driver_speed_mps: float = field(
        default=1.0, metadata={"unit": "m/s", "doc": "... at a speed within this is the same driver and raises no "
                                                     "second alarm; 0 = every track raises its own",
                               "min": 0.0, "max": 50.0})
    stopped_speed_mps: float = field(
        default=1.0, metadata={"unit": "m/s", "doc": "a vehicle slower than this is standing", "min": 0.0, "max": 20.0})
    stopped_min_s: float = field(
        default=5.0, metadata={"unit": "s", "doc": "standing this long in a lane raises stopped_vehicle",
                               "min": 0.0, "max": 3600.0})
    moving_speed_mps: float = field(
        default=4.0, metadata={"unit": "m/s", "doc": "a track must have been this fast to count as a vehicle that "
                                                     "stopped (static clutter never is); also re-arms the event",
                               "min": 0.0, "max": 100.0})

    def __post_init__(self) -> None:
        n = len(self.lane_centers_m)
        if len(self.lane_widths_m) not in (1, n):
            raise ValueError(f"lane_widths_m needs 1 or {n} values, got {len(self.lane_widths_m)}")
        if len(self.lane_directions) not in (1, n):
            raise ValueError(f"lane_directions needs 1 or {n} values, got {len(self.lane_directions)}")
        bad = [d for d in self.lane_directions if d not in ("toward", "away")]
        if bad:
            raise ValueError(f"lane_directions must be toward or away, got {bad}")
        if len(self.length_class_names) != len(self.length_class_edges_m) + 1:
            raise ValueError("length_class_names needs one more entry than length_class_edges_m")
        if list(self.length_class_edges_m) != sorted(self.length_class_edges_m):
            raise ValueError("length_class_edges_m must be increasing")
        if len(self.length_range_m) != 2 or not self.length_range_m[0] < self.length_range_m[1]:
            raise ValueError("length_range_m needs two increasing values (nearest, farthest)")
