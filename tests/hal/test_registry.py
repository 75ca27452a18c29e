import pytest

from hal import SourceUrlError, open_radar
from hal.sim import SimSource


def test_open_radar_returns_unopened_backend():
    src = open_radar("sim://simo?scenario=single-car&seed=3&realtime=0")
    assert isinstance(src, SimSource) and not src.is_open
    assert src.seed_opt == 3 and src.realtime is False


@pytest.mark.parametrize(
    "url, match",
    [
        ("bogus://x", "unknown source scheme 'bogus://'.*sim://simo"),
        ("/dev/ttyACM0", "not a source URL"),
        ("sim://simo?speed=3", "unknown option.*speed.*allowed: scenario"),
        ("sim://simo?seed=abc", "bad value 'abc' for option 'seed'"),
        ("sim://simo?realtime=maybe", "realtime"),
        ("sim://radar", "unknown simulated board 'radar'"),
        ("sim://", "needs a board"),
        ("replay://", "needs a file"),
        ("replay://x.npz?speed=-1", "speed"),
        ("sim://simo?seed=1&seed=2", "given twice"),
    ],
)
def test_bad_urls_show_the_expected_form(url, match):
    with pytest.raises(SourceUrlError, match="(?s)" + match):
        open_radar(url)


def test_unknown_scenario_and_board_mismatch_fail_at_open():
    with pytest.raises(SourceUrlError, match="(?s)unknown scenario 'nope'.*highway4"):
        open_radar("sim://simo?scenario=nope").open()
    with pytest.raises(SourceUrlError, match="for board 'd2g'.*sim://d2g"):
        open_radar("sim://simo?scenario=tavanti-test1").open()


def test_overrides_win_over_url_options():
    src = open_radar("sim://d2g?seed=1", seed=9, realtime=False)
    assert src.seed_opt == 9 and src.realtime is False
    with pytest.raises(SourceUrlError, match="unknown option"):
        open_radar("sim://d2g", colour="red")
