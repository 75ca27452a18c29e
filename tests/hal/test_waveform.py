"""The derived characteristics reproduce Lim Table 2 and Tavanti Table II."""

import math

import pytest

from hal import ChirpSegment, Waveform, characteristics, d2g_frontend, simo_frontend


def test_simo_reproduces_lim_table_2():
    fe = simo_frontend()
    ch = characteristics(fe)
    assert ch.range_resolution_m == pytest.approx(0.75, abs=0.005)  # paper rounds to 0.8
    assert ch.radial_speed_resolution_mps == pytest.approx(1.24, abs=0.01)  # paper: 1.2
    assert ch.max_radial_speed_mps * 3.6 >= 250.0  # +-250 km/h detectable at 300 m
    assert ch.max_radial_speed_mps * 3.6 < 260.0  # and the sample rate is not wastefully high
    assert ch.max_unambiguous_range_m >= 300.0
    assert ch.unambiguous_angle_deg == pytest.approx(19.47, abs=0.05)
    assert ch.unambiguous_angle_deg > ch.fov_deg / 2 == 15.0
    assert ch.frame_period_s == pytest.approx(0.033)
    # the four-segment schedule of Lim Fig. 7: up 5, down 5, up 10, down 10 ms over 200 MHz
    segs = fe.waveform.segments
    assert [s.direction for s in segs] == [1, -1, 1, -1]
    assert [s.ramp_s for s in segs] == [5e-3, 5e-3, 10e-3, 10e-3]
    assert all(s.bandwidth_hz == 200e6 for s in segs)
    assert fe.rx_spacing_m == pytest.approx(1.5 * fe.waveform.wavelength_m)
    assert fe.frame_shape == (4, 4, 1024)


def test_d2g_reproduces_tavanti_table_2():
    fe = d2g_frontend()
    ch = characteristics(fe)
    assert ch.range_resolution_m == pytest.approx(0.75, abs=0.005)
    assert ch.max_unambiguous_range_m == pytest.approx(24.0, abs=0.05)  # N_s c / (4 B)
    assert ch.max_radial_speed_mps * 3.6 == pytest.approx(5.4, abs=0.06)  # lambda / (4 T_PRI)
    assert ch.radial_speed_resolution_mps * 3.6 == pytest.approx(0.5, abs=0.05)
    assert ch.frame_period_s == pytest.approx(0.2)
    assert ch.unambiguous_angle_deg is None
    seg = fe.waveform.segments[0]
    assert (seg.n_chirps, seg.n_samples, seg.ramp_s, seg.pri_s) == (21, 64, 1.5e-3, 2.1e-3)
    assert fe.waveform.carrier_hz == 24.025e9
    assert fe.frame_shape == (1, 21, 64)


def test_round_trip_json():
    fe = simo_frontend()
    from hal import FrontendInfo

    assert FrontendInfo.from_json(fe.to_json()) == fe


@pytest.mark.parametrize(
    "kwargs, msg",
    [
        (dict(direction=0), "direction"),
        (dict(n_samples=0), "n_samples"),
        (dict(n_samples=2000), "beyond the ramp"),
        (dict(n_chirps=3, pri_s=1e-4), "pri_s"),
    ],
)
def test_bad_segments_are_refused(kwargs, msg):
    base = dict(direction=1, ramp_s=1e-3, bandwidth_hz=1e8, f_start_hz=24e9, n_samples=64, sample_rate_hz=1e5)
    base.update(kwargs)
    with pytest.raises(ValueError, match=msg):
        ChirpSegment(**base)


def test_schedule_longer_than_frame_is_refused():
    seg = ChirpSegment(1, 1e-3, 1e8, 24e9, 64, 1e5, n_chirps=10, pri_s=2e-3)
    with pytest.raises(ValueError, match="longer than the frame"):
        Waveform("x", 24e9, (seg,), frame_period_s=0.01)
    assert math.isclose(Waveform("x", 24e9, (seg,), frame_period_s=0.05).n_chirps, 10)


def test_clipped_samples_counts_both_rails_of_i_and_q():
    import numpy as np

    from hal.frame import RawFrame
    from hal.waveform import d2g_frontend

    fe = d2g_frontend()
    i = np.zeros(fe.frame_shape, dtype=np.int16)
    q = np.zeros(fe.frame_shape, dtype=np.int16)
    i.flat[:3] = fe.adc_max
    q.flat[-2:] = fe.adc_min
    q.flat[5] = fe.adc_max - 1  # one code below full scale: not clipped
    frame = RawFrame(seq=0, t_ns=0, i=i, q=q, frontend=fe)
    assert frame.clipped_samples() == (5, 2 * i.size)
