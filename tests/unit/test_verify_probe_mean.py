"""verify's probe_mean measurement (simcli/verify/measure.py): a finite sensor read as the mean of point
probes along it (the wall band 0.07-0.16 m of Buchner's dam break, cases sph_buchner_2d_*_p1_line_impulse); a
dry sample (NaN) counts as 0."""

import h5py
import numpy as np
import pytest

from simcli.verify.measure import probe_mean


def test_probe_mean_averages_the_probes_with_dry_samples_as_zero(tmp_path):
    path = tmp_path / "sim.h5"
    t = np.array([0.0, 0.1, 0.2])
    with h5py.File(path, "w") as f:
        for name, vals in (("a", [np.nan, 2.0, 4.0]), ("b", [1.0, 4.0, 8.0])):
            g = f.create_group(f"probes/{name}")
            g["time"] = t
            g["value"] = np.asarray(vals)
    with h5py.File(path, "r") as f:
        tt, v = probe_mean(f, names=["a", "b"])
        np.testing.assert_allclose(tt, t)
        np.testing.assert_allclose(v, [0.5, 3.0, 6.0])
        with pytest.raises(KeyError, match="names"):
            probe_mean(f)
