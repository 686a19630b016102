"""Input checks shared by the learning core's estimators."""

import numpy as np
import pytest

from policy_align_ros.learning.fitting import check_finite


def test_check_finite_returns_a_float_array_and_names_the_bad_item():
    np.testing.assert_array_equal(check_finite("goal", [1, 2], (2,)), [1.0, 2.0])
    assert check_finite("goal", [1, 2], (2,)).dtype == float
    with pytest.raises(ValueError, match=r"^drops\b"):
        check_finite("drops", [1.0, np.nan], (2,))
    with pytest.raises(ValueError, match=r"^motion\b.*\(3, 2\)"):
        check_finite("motion", np.zeros((2, 2)), (3, 2))
