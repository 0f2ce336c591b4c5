"""studies.vgn_first_contact without a simulation: the span of an object across the
closing axis where an off-centre pad meets it first, the finger tips' last 10 mm."""
import numpy as np

from sim_bridge.physics import panda_hand
from sim_bridge.studies import vgn_first_contact as vfc


def test_the_span_across_the_closing_axis_counts_only_the_pads_slab_at_the_tips():
    tip = panda_hand.FINGER_DEPTH_M
    points = np.array([[0.0, -0.044, tip - 0.005],   # in the slab, at the tips: counted
                       [0.005, 0.021, tip - 0.001],  # counted
                       [0.0, 0.060, tip - 0.020],    # 20 mm short of the tips: not
                       [0.030, -0.070, tip - 0.005],  # beside the pads (|x| > half width): not
                       [0.0, 0.070, tip + 0.002]])   # past the tips: not
    assert vfc.across_closing_axis(points) == (-0.044, 0.021)
    assert vfc.across_closing_axis(points[2:]) is None
