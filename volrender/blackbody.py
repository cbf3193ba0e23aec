"""Blackbody colours: Planck's law -> CIE 1931 XYZ -> linear Rec.709, and the table the
volume kernels read (cl/volume.h vr_blackbody).

Colour-matching functions: the CIE 1931 2-degree standard observer tabulated at 5 nm
(CIE 015, 380-780 nm; standard data), summed at 5 nm as CIE 015 recommends. The columns
integrate to the CIE's 106.857 each, the table stays within the accuracy of Wyman, Sloan
and Shirley's published analytic fit (`cmf_fit`, JCGT 2(2), 2013), and the blackbody
chromaticities it gives match the tabulated Planckian locus to 1e-4 from 1000 K to
10 000 K (tests/test_blackbody.py checks all three).

Normalisation (`rgb`): XYZ -> linear Rec.709 (sRGB primaries, the D65 matrix), then
white-balanced by the 6500 K blackbody (each channel divided by its value at 6500 K, so
6500 K is exactly (1, 1, 1); the 6500 K Planckian lies 0.005 from D65 in xy, a faint
magenta that this removes), out-of-gamut negatives clipped to 0, and divided by the
largest channel: a chromaticity with its brightest channel 1. The emission grid gives
the intensity. 1500 K -> (1, 0.14, 0); 3000 K -> (1, 0.51, 0.16); 12 000 K -> (0.53,
0.67, 1).

Intensity law (`radiance`, `--emission-law blackbody`, the default with a temperature
grid; issue #22): the emitted radiance per unit length per emission-grid value is
    L_e(T) = sigma_SB T^4 / pi x 1e-6 x rgb(T) / Y(rgb(T)),
Blender's Principled Volume with Blackbody Intensity 1 (Cycles: the Stefan-Boltzmann
exitance over pi, scaled by 1e-6, with the colour normalised to luminance 1, Y the
Rec.709 luminance of the linear colour): it rises as T^4, 1000 K -> Y 0.018, 1500 K ->
0.091, 3000 K -> 1.46. Below the table's range (800 K) the colour is clamped but the
T^4 factor is not, so cold voxels fade to black.
"""
from __future__ import annotations

import numpy as np

T_MIN, T_MAX = 800.0, 12000.0     # the table's range, kelvin (clamped outside)
TABLE_SIZE = 512                  # entries, uniform in 1/T (mired): interpolation error <= 0.0022
WHITE_K = 6500.0
SIGMA_SB = 5.670374419e-8         # Stefan-Boltzmann constant, W m^-2 K^-4
# L_e = INTENSITY_K T^4 x (colour of luminance 1): Blender's blackbody intensity
INTENSITY_K = SIGMA_SB * 1e-6 / np.pi
REC709_Y = np.array([0.2126, 0.7152, 0.0722])

# CIE 1931 2-degree observer: (nm, x-bar, y-bar, z-bar)
CIE_1931_5NM = np.array([
    (380, 0.001368, 0.000039, 0.006450),
    (385, 0.002236, 0.000064, 0.010550),
    (390, 0.004243, 0.000120, 0.020050),
    (395, 0.007650, 0.000217, 0.036210),
    (400, 0.014310, 0.000396, 0.067850),
    (405, 0.023190, 0.000640, 0.110200),
    (410, 0.043510, 0.001210, 0.207400),
    (415, 0.077630, 0.002180, 0.371300),
    (420, 0.134380, 0.004000, 0.645600),
    (425, 0.214770, 0.007300, 1.039050),
    (430, 0.283900, 0.011600, 1.385600),
    (435, 0.328500, 0.016840, 1.622960),
    (440, 0.348280, 0.023000, 1.747060),
    (445, 0.348060, 0.029800, 1.782600),
    (450, 0.336200, 0.038000, 1.772110),
    (455, 0.318700, 0.048000, 1.744100),
    (460, 0.290800, 0.060000, 1.669200),
    (465, 0.251100, 0.073900, 1.528100),
    (470, 0.195360, 0.090980, 1.287640),
    (475, 0.142100, 0.112600, 1.041900),
    (480, 0.095640, 0.139020, 0.812950),
    (485, 0.057950, 0.169300, 0.616200),
    (490, 0.032010, 0.208020, 0.465180),
    (495, 0.014700, 0.258600, 0.353300),
    (500, 0.004900, 0.323000, 0.272000),
    (505, 0.002400, 0.407300, 0.212300),
    (510, 0.009300, 0.503000, 0.158200),
    (515, 0.029100, 0.608200, 0.111700),
    (520, 0.063270, 0.710000, 0.078250),
    (525, 0.109600, 0.793200, 0.057250),
    (530, 0.165500, 0.862000, 0.042160),
    (535, 0.225750, 0.914850, 0.029840),
    (540, 0.290400, 0.954000, 0.020300),
    (545, 0.359700, 0.980300, 0.013400),
    (550, 0.433450, 0.994950, 0.008750),
    (555, 0.512050, 1.000000, 0.005750),
    (560, 0.594500, 0.995000, 0.003900),
    (565, 0.678400, 0.978600, 0.002750),
    (570, 0.762100, 0.952000, 0.002100),
    (575, 0.842500, 0.915400, 0.001800),
    (580, 0.916300, 0.870000, 0.001650),
    (585, 0.978600, 0.816300, 0.001400),
    (590, 1.026300, 0.757000, 0.001100),
    (595, 1.056700, 0.694900, 0.001000),
    (600, 1.062200, 0.631000, 0.000800),
    (605, 1.045600, 0.566800, 0.000600),
    (610, 1.002600, 0.503000, 0.000340),
    (615, 0.938400, 0.441200, 0.000240),
    (620, 0.854450, 0.381000, 0.000190),
    (625, 0.751400, 0.321000, 0.000100),
    (630, 0.642400, 0.265000, 0.000050),
    (635, 0.541900, 0.217000, 0.000030),
    (640, 0.447900, 0.175000, 0.000020),
    (645, 0.360800, 0.138200, 0.000010),
    (650, 0.283500, 0.107000, 0.000000),
    (655, 0.218700, 0.081600, 0.000000),
    (660, 0.164900, 0.061000, 0.000000),
    (665, 0.121200, 0.044580, 0.000000),
    (670, 0.087400, 0.032000, 0.000000),
    (675, 0.063600, 0.023200, 0.000000),
    (680, 0.046770, 0.017000, 0.000000),
    (685, 0.032900, 0.011920, 0.000000),
    (690, 0.022700, 0.008210, 0.000000),
    (695, 0.015840, 0.005723, 0.000000),
    (700, 0.011359, 0.004102, 0.000000),
    (705, 0.008111, 0.002929, 0.000000),
    (710, 0.005790, 0.002091, 0.000000),
    (715, 0.004109, 0.001484, 0.000000),
    (720, 0.002899, 0.001047, 0.000000),
    (725, 0.002049, 0.000740, 0.000000),
    (730, 0.001440, 0.000520, 0.000000),
    (735, 0.001000, 0.000361, 0.000000),
    (740, 0.000690, 0.000249, 0.000000),
    (745, 0.000476, 0.000172, 0.000000),
    (750, 0.000332, 0.000120, 0.000000),
    (755, 0.000235, 0.000085, 0.000000),
    (760, 0.000166, 0.000060, 0.000000),
    (765, 0.000117, 0.000042, 0.000000),
    (770, 0.000083, 0.000030, 0.000000),
    (775, 0.000059, 0.000021, 0.000000),
    (780, 0.000042, 0.000015, 0.000000),
])

XYZ_TO_REC709 = np.array([[3.2404542, -1.5371385, -0.4985314],
                          [-0.9692660, 1.8760108, 0.0415560],
                          [0.0556434, -0.2040259, 1.0572252]])
_H, _C, _K = 6.62607015e-34, 2.99792458e8, 1.380649e-23

# (weight, peak nm, width below the peak, width above): Wyman et al. 2013, multi-lobe fit
_LOBES = {
    "x": ((1.056, 599.8, 37.9, 31.0), (0.362, 442.0, 16.0, 26.7), (-0.065, 501.1, 20.4, 26.2)),
    "y": ((0.821, 568.8, 46.9, 40.5), (0.286, 530.9, 16.3, 31.1)),
    "z": ((1.217, 437.0, 11.8, 36.0), (0.681, 459.0, 26.0, 13.8)),
}


def cmf_fit(lam_nm) -> np.ndarray:
    """Wyman et al.'s analytic fit of the CIE 1931 functions (an independent check of the
    table): shape (..., 3)."""
    lam = np.asarray(lam_nm, np.float64)
    out = []
    for key in "xyz":
        v = np.zeros_like(lam)
        for w, mu, s1, s2 in _LOBES[key]:
            s = np.where(lam < mu, s1, s2)
            v = v + w * np.exp(-0.5 * ((lam - mu) / s) ** 2)
        out.append(v)
    return np.stack(out, axis=-1)


def planck(lam_nm, kelvin) -> np.ndarray:
    """Spectral radiance of a blackbody (W sr^-1 m^-3) at wavelengths in nm: (..., n)."""
    lam = np.asarray(lam_nm, np.float64) * 1e-9
    t = np.asarray(kelvin, np.float64)[..., None]
    with np.errstate(over="ignore"):
        return 2 * _H * _C ** 2 / (lam ** 5 * np.expm1(_H * _C / (lam * _K * t)))


def xyz(kelvin) -> np.ndarray:
    """CIE XYZ of a blackbody, normalised to Y = 1: shape (..., 3)."""
    v = planck(CIE_1931_5NM[:, 0], kelvin) @ CIE_1931_5NM[:, 1:]
    return v / v[..., 1:2]


def chromaticity(kelvin) -> np.ndarray:
    """CIE 1931 (x, y) of a blackbody."""
    v = xyz(kelvin)
    return v[..., :2] / v.sum(axis=-1, keepdims=True)


def linear_rec709(kelvin) -> np.ndarray:
    """Linear Rec.709 RGB of XYZ(T) with Y = 1 (no white balance, negatives kept)."""
    return xyz(kelvin) @ XYZ_TO_REC709.T


_WHITE = linear_rec709(WHITE_K)


def rgb(kelvin) -> np.ndarray:
    """The emission colour of a blackbody (module docstring: white-balanced to 6500 K,
    negatives clipped, brightest channel 1): shape (..., 3)."""
    v = np.clip(linear_rec709(kelvin) / _WHITE, 0.0, None)
    return v / v.max(axis=-1, keepdims=True)


def radiance(kelvin) -> np.ndarray:
    """The blackbody intensity law (module docstring): INTENSITY_K T^4 rgb(T) / Y(rgb(T)),
    shape (..., 3); the colour clamped to [T_MIN, T_MAX] as the kernel's table is."""
    t = np.asarray(kelvin, np.float64)
    c = rgb(np.clip(t, T_MIN, T_MAX))
    return (INTENSITY_K * np.maximum(t, 0.0) ** 4)[..., None] * c / (c @ REC709_Y)[..., None]


def table(n: int = TABLE_SIZE, t_min: float = T_MIN, t_max: float = T_MAX) -> np.ndarray:
    """float32 (n, 4): rgb(T) at n temperatures uniform in 1/T, from t_max (entry 0) to
    t_min (entry n - 1), and in w 1 / its luminance (the intensity law's normalisation);
    the kernel interpolates linearly in 1/T and clamps outside."""
    inv = np.linspace(1.0 / t_max, 1.0 / t_min, n)
    out = np.zeros((n, 4), np.float32)
    c = rgb(1.0 / inv)
    out[:, :3] = c
    out[:, 3] = 1.0 / (c @ REC709_Y)
    return out


def lookup(kelvin, tab=None, t_min: float = T_MIN, t_max: float = T_MAX) -> np.ndarray:
    """What the kernel reads from `tab` at temperature `kelvin` (numpy oracle)."""
    tab = table() if tab is None else tab
    n = len(tab)
    t = np.clip(np.asarray(kelvin, np.float64), t_min, t_max)
    f = (1.0 / t - 1.0 / t_max) / (1.0 / t_min - 1.0 / t_max) * (n - 1)
    i = np.clip(np.floor(f).astype(int), 0, n - 2)
    a = (f - i)[..., None]
    return (1 - a) * tab[i, :3] + a * tab[i + 1, :3]


def lookup_radiance(kelvin, tab=None) -> np.ndarray:
    """What the kernel emits under the intensity law at `kelvin` (numpy oracle): the
    table's colour and 1/luminance, interpolated, times INTENSITY_K T^4."""
    tab = table() if tab is None else tab
    t = np.asarray(kelvin, np.float64)
    ext = np.concatenate([tab[:, :3], tab[:, 3:4] * np.ones((1, 3))], axis=1)
    n = len(tab)
    tc = np.clip(t, T_MIN, T_MAX)
    f = (1.0 / tc - 1.0 / T_MAX) / (1.0 / T_MIN - 1.0 / T_MAX) * (n - 1)
    i = np.clip(np.floor(f).astype(int), 0, n - 2)
    a = (f - i)[..., None]
    v = (1 - a) * ext[i] + a * ext[i + 1]
    return (INTENSITY_K * np.maximum(t, 0.0) ** 4)[..., None] * v[..., :3] * v[..., 3:4]
