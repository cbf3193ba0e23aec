"""Henyey-Greenstein in the kernel: normalisation, mean cosine, mixing, sign."""
import numpy as np
import pyopencl as cl
import pytest

from volrender import reference

SRC = """
#include "common.h"
#include "phase.h"
__kernel void eval(__global const float* mu, __global float* out, float4 ph)
{
    int i = get_global_id(0);
    out[i] = vr_phase(mu[i], ph);
}
"""


def kernel_phase(dev, mu, g1, g2=0.0, w=1.0):
    prg = dev.build(SRC, {"VR_PHASE_MIXED": int(w < 1.0)}, "phase probe")
    mu = np.ascontiguousarray(mu, np.float32)
    out = np.empty_like(mu)
    mf = cl.mem_flags
    d_mu = cl.Buffer(dev.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=mu)
    d_out = cl.Buffer(dev.context, mf.WRITE_ONLY, out.nbytes)
    cl.Kernel(prg, "eval")(dev.queue, mu.shape, None, d_mu, d_out,
                           np.array([g1, g2, w, 0], np.float32))
    cl.enqueue_copy(dev.queue, out, d_out)
    return out.astype(np.float64)


def sphere_integrals(dev, g1, g2=0.0, w=1.0):
    """(integral of p, integral of p*mu) over the sphere. Each half of mu in [-1, 1] is
    integrated by Gauss-Legendre in v = log(1 -+ mu), which resolves the peaks of
    |g| -> 1 lobes (width ~ (1-|g|)^2) at both ends."""
    x, wt = np.polynomial.legendre.leggauss(300)
    lo = np.log(1e-12)
    v = lo + 0.5 * (x + 1.0) * (0.0 - lo)
    dv = 0.5 * (0.0 - lo) * wt * np.exp(v)        # dmu = e^v dv on both halves
    mu = np.concatenate([1.0 - np.exp(v), -1.0 + np.exp(v)])
    weights = np.concatenate([dv, dv])
    p = kernel_phase(dev, mu, g1, g2, w)
    return 2 * np.pi * np.sum(weights * p), 2 * np.pi * np.sum(weights * p * mu)


@pytest.mark.parametrize("g", [-0.9, -0.5, 0.0, 0.3, 0.7, 0.9])
def test_hg_lobe_integrates_to_one_with_mean_cosine_g(cl_device, g):
    total, mean = sphere_integrals(cl_device, g)
    assert total == pytest.approx(1.0, abs=2e-4)
    assert mean == pytest.approx(g, abs=2e-4)


def test_mixture_integrates_to_one_and_is_linear_in_w(cl_device):
    total, mean = sphere_integrals(cl_device, 0.8, -0.4, 0.7)
    assert total == pytest.approx(1.0, abs=2e-4)
    assert mean == pytest.approx(0.7 * 0.8 + 0.3 * -0.4, abs=2e-4)
    mu = np.linspace(-1, 1, 101)
    np.testing.assert_allclose(kernel_phase(cl_device, mu, 0.8, -0.4, 0.7),
                               reference.phase(mu, 0.8, -0.4, 0.7), rtol=1e-5)


def test_forward_sign_convention(cl_device):
    """g > 0: mu = +1 (scattered along the light's propagation) is the peak."""
    fwd, back = kernel_phase(cl_device, [1.0, -1.0], 0.6)
    assert fwd > 10 * back
    assert fwd == pytest.approx(reference.hg(1.0, 0.6), rel=1e-5)


def test_near_delta_lobe_stays_finite_and_matches_reference(cl_device):
    """|g| = 0.999 (the clamp): a float32 mu resolves the peak (width ~1e-6) only
    coarsely, so compare with the float64 formula at the same float32 mu, and check
    normalisation where float32 mu resolves the lobe (|g| = 0.99)."""
    mu = np.concatenate([[1.0, -1.0, 0.0], 1.0 - np.geomspace(1e-7, 2.0, 200)])
    mu32 = mu.astype(np.float32).astype(np.float64)
    for g in (0.999, -0.999):
        vals = kernel_phase(cl_device, mu, g)
        assert np.all(np.isfinite(vals)) and np.all(vals > 0)
        np.testing.assert_allclose(vals, reference.hg(mu32, g), rtol=2e-4)
    for g in (0.99, -0.99):
        assert sphere_integrals(cl_device, g)[0] == pytest.approx(1.0, abs=1e-3)
