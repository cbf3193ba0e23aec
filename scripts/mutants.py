"""Mutation check: does the test suite notice deliberate bugs in the physics?

    .venv/bin/python scripts/mutants.py [-k SUBSTRING ...] [--from N] [--list] [--write]
                                         [--no-baseline] [--timeout SECONDS]

Each mutant is (file, an exact snippet of it, its replacement, the tests to run). The
working tree (tracked and untracked, not ignored files) is copied once to a temporary
folder; every mutant is applied there alone, its tests run (pytest -x, from the copy,
which imports the copy's volrender and builds the copy's cl/), and the file is restored.
The working tree itself is never touched. Results:

    killed     a named test failed
    survived   every named test passed: a gap in the tests, unless the mutant's note
               says why no test can see it (an equivalent mutant)
    stale      the snippet is not in the file (the code moved on: update the mutant)
    ambiguous  the snippet occurs more than once (give more context)
    broken     the mutant does not build (an OpenCL build error): not a useful mutant
    error      pytest could not run the tests (collection error, timeout)

Before the mutants, the named tests run once on the unmutated copy (a baseline): a test
that fails there would "kill" every mutant, so the run stops (--no-baseline skips it).
-k is repeatable (a mutant whose name contains any of them runs). --write puts the table
into docs/testing.md between its mutants markers; after a partial run (-k, --from) the rows
of the mutants not run are kept from the table there. Not part of CI: a full run takes
about 20 minutes on 2 cores (each mutant recompiles its kernels).
"""
from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "testing.md"
BEGIN, END = "<!-- mutants:begin -->", "<!-- mutants:end -->"


@dataclass(frozen=True)
class Mutant:
    name: str
    file: str
    old: str
    new: str
    tests: tuple          # pytest invocations, each one string of arguments
    note: str = ""        # for a mutant no test can see: why (checked by a survivor's row)


M = Mutant
OPTICS = "tests/test_optics.py"
DEPTH = "tests/test_depth.py"
ENVS = "tests/test_env_sampling.py"
THICK = "tests/test_thick_media.py"
GEN = "tests/test_generic_params.py"

MUTANTS = [
    # ------------------------------------------------------------ glass optics (cl/glass.h)
    M("fresnel: p-polarised replaced by s (rp = rs)", "cl/glass.h",
      "float rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);", "float rp = rs;",
      (f"{OPTICS} -k fresnel or brewster",
       "tests/test_glass.py -k fresnel or snell or ior_one",
       "tests/test_extreme.py -k extreme_ior")),
    M("fresnel: sum instead of the mean of rs^2 and rp^2", "cl/glass.h",
      "return 0.5f * (rs * rs + rp * rp);", "return rs * rs + rp * rp;",
      (f"{OPTICS} -k fresnel",)),
    M("fresnel: TIR reflects 0.9", "cl/glass.h",
      "    if (s2 >= 1.0f)\n        return 1.0f;", "    if (s2 >= 1.0f)\n        return 0.9f;",
      (f"{OPTICS} -k fresnel",)),
    M("refraction: wrong sign of the normal term", "cl/glass.h",
      "*t = normalize(eta * d + (eta * cos_i - sqrt(1.0f - s2)) * n);",
      "*t = normalize(eta * d + (eta * cos_i + sqrt(1.0f - s2)) * n);",
      ("tests/test_glass.py -k snell",)),
    M("reflection: d - (d.n) n (half the normal component)", "cl/glass.h",
      "return d - 2.0f * dot(d, n) * n;", "return d - dot(d, n) * n;",
      (f"{OPTICS} -k closed_form or trapped",)),
    # ------------------------------------------------------------ glass shading (shade_glass.h)
    M("full model: TIR keeps half its throughput", "cl/shade_glass.h",
      "/* ior < 1 outside: F = 1 */\n                d = e.refl;",
      "/* ior < 1 outside: F = 1 */\n                thr *= 0.5f;\n                d = e.refl;",
      (f"{OPTICS} -k trapped or total_reflection", "tests/test_extreme.py -k total_internal")),
    M("fast model: TIR keeps half its throughput", "cl/shade_glass.h",
      "/* ior < 1: F = 1, counted above */\n            d = e.refl;",
      "/* ior < 1: F = 1, counted above */\n            thr *= 0.5f;\n            d = e.refl;",
      (f"{OPTICS} -k trapped or two_spheres", "tests/test_extreme.py -k total_internal")),
    M("opaque diffuse: Lambert's 1/pi dropped", "cl/shade_glass.h",
      "diffuse += li * fmax(dot(e->n, l), 0.0f) * (1.0f / VR_PI);",
      "diffuse += li * fmax(dot(e->n, l), 0.0f);",
      (f"{OPTICS} -k opaque",)),
    M("opaque diffuse: the environment along the mirror direction, not the normal",
      "cl/shade_glass.h", "float3 diffuse = glass_env(gp, env, e->n);",
      "float3 diffuse = glass_env(gp, env, e->refl);", (f"{OPTICS} -k opaque",)),
    M("opaque: the tint not weighted by 1 - F", "cl/shade_glass.h",
      "return (1.0f - e->fr) * e->col * diffuse;", "return e->col * diffuse;",
      (f"{OPTICS} -k opaque",)),
    M("Beer-Lambert at half strength", "cl/shade_glass.h",
      "thr *= exp(-tau);", "thr *= exp(-0.5f * tau);", (f"{OPTICS} -k ior_one",)),
    M("glow: emitted light not attenuated inside the glass", "cl/shade_glass.h",
      "float3 w = select(-expm1(-tau) / tau, (float3)(1.0f),\n"
      "                                  isless(tau, (float3)(1e-6f)));",
      "float3 w = (float3)(1.0f);", (f"{OPTICS} -k ior_one",)),
    M("glow without absorption: half the chord", "cl/shade_glass.h",
      "*rgb += *thr * gp->glow * tint * *t;", "*rgb += *thr * gp->glow * tint * 0.5f * *t;",
      (f"{OPTICS} -k ior_one",)),
    M("Blinn-Phong normalisation (s + 2) / (2 pi)", "cl/shade_glass.h",
      "float norm = (gp->shininess + 8.0f) * (1.0f / (8.0f * VR_PI));",
      "float norm = (gp->shininess + 2.0f) * (1.0f / (2.0f * VR_PI));",
      (f"{OPTICS} -k opaque",)),
    M("highlights without n.l", "cl/shade_glass.h",
      "float3 c = w * e * ndl * norm * pow(ndh, gp->shininess);",
      "float3 c = w * e * norm * pow(ndh, gp->shininess);", (f"{OPTICS} -k opaque",)),
    M("fast model: refraction keeps the reflected share (thr *= 1 - F dropped)",
      "cl/shade_glass.h", "thr *= 1.0f - e.fr;", "thr *= 1.0f;",
      ("tests/test_extreme.py -k extreme_ior", f"{OPTICS} -k trapped")),
    M("mirror reflection not weighted by F", "cl/shade_glass.h",
      "rgb += thr * (e.fr * gp->reflectivity) * glass_env(gp, env, e.refl);",
      "rgb += thr * gp->reflectivity * glass_env(gp, env, e.refl);", (f"{OPTICS} -k opaque",)),
    M("highlights not weighted by F", "cl/shade_glass.h",
      "base, thr * e.fr, seed,", "base, thr, seed,",
      (f"{OPTICS} -k opaque",)),
    M("point lights fall off as 1/r", "cl/shade_glass.h",
      "e /= fmax(r2, 1e-12f * gp->scale * gp->scale);",
      "e /= fmax(*dist, 1e-12f * gp->scale * gp->scale);", (f"{OPTICS} -k closed_form",)),
    M("hard shadows let half the light through", "cl/shade_glass.h",
      "                              gp->relax, gp->shadow_cone, &vis, &t, &s))\n        return 0.0f;",
      "                              gp->relax, gp->shadow_cone, &vis, &t, &s))\n        return 0.5f;",
      (f"{OPTICS} -k closed_form",)),
    M("penumbra without the smoothstep", "cl/shade_glass.h",
      "return vis * vis * (3.0f - 2.0f * vis);", "return vis;",
      ("tests/test_glass_dispatch.py -k soft_shadows",),
      note="not physics: the soft shadow is Quilez's penumbra estimate (an approximation, "
           "cl/shade_glass.h), whose ramp shape is a look; test_soft_shadows checks what it "
           "promises (never brighter than the hard shadow; a band of partly lit pixels)"),
    M("eta inverted (n_t / n_i)", "cl/shade_glass.h",
      "float eta = inside ? gp->ior : 1.0f / gp->ior;",
      "float eta = inside ? 1.0f / gp->ior : gp->ior;",
      (f"{OPTICS} -k trapped or opaque",)),
    # ------------------------------------------------------------ glass paths (issue 21)
    M("full model: the exit's internal reflection dropped", "cl/shade_glass.h",
      "rb.thr = thr * (e.fr * gp->reflectivity);",
      "rb.thr = thr * (e.fr * gp->reflectivity) * (inside ? 0.0f : 1.0f);",
      ("tests/test_glass_paths.py", "tests/test_extreme.py -k furnace or grazing")),
    M("full model: roulette survivors keep their weight (biased dark)", "cl/shade_glass.h",
      "other.thr *= rr / w;", "other.thr *= 1.0f;",
      ("tests/test_glass_paths.py -k vanishes or mitsuba", "tests/test_extreme.py -k furnace")),
    M("full model: the split branch is never traced", "cl/shade_glass.h",
      "                    stack[sp++] = other;", "                    (void)other;",
      ("tests/test_glass_paths.py", "tests/test_extreme.py -k furnace")),
    M("full model: a merged branch's weight lost", "cl/shade_glass.h",
      "go.thr += other.thr;                 /* past the budget: merged */",
      "(void)other;                 /* past the budget: merged */",
      ("tests/test_extreme.py -k furnace or grazing", "tests/test_glass_paths.py")),
    M("transmissive shadows: the exit's Fresnel dropped", "cl/shade_glass.h",
      "trans *= 1.0f - glass_fresnel(clamp(dot(d, n), 0.0f, 1.0f), gp->ior);",
      "trans *= 1.0f;", ("tests/test_glass_paths.py -k shadow",)),
    M("transmissive shadows: no absorption along the chord", "cl/shade_glass.h",
      "trans *= exp(-gp->absorption.xyz * t);", "trans *= 1.0f;",
      ("tests/test_glass_paths.py -k shadow",)),
    M("relaxed step past the march's end ends it (the lost-ray bug)", "cl/sdf.h",
      "if ((past || skip) && w > 1.0f && step > 0.0f) {",
      "if (skip && w > 1.0f && step > 0.0f) {",
      ("tests/test_glass.py -k relaxed", f"{OPTICS} -k ior_one")),
    M("hit threshold not capped at hit_len", "cl/sdf.h",
      "if (f < eps * fmin(base + t, sc->hit_len)) {", "if (f < eps * (base + t)) {",
      ("tests/test_cells.py -k far_away or brute_force", "tests/test_glass.py -k accelerations")),
    # ------------------------------------------------------------ glass kernel (render_glass.cl)
    M("samples above 1e20 replaced by 0", "cl/render_glass.cl",
      "        acc.rgb += vr_safe_sample(glass_path(&sc, gp, lights, env, cam->origin.xyz, d, cam->seed,\n"
      "                                             pixel, (uint)s, &covered));",
      "        { float3 l_ = vr_safe_sample(glass_path(&sc, gp, lights, env, cam->origin.xyz, d,\n"
      "          cam->seed, pixel, (uint)s, &covered)); acc.rgb += select(l_, (float3)(0.0f),\n"
      "          isgreater(l_, (float3)(1e20f))); }",
      ("tests/test_extreme.py -k glass_knobs or texels_beyond",)),
    # ------------------------------------------------------------ the field (cl/sdf.h)
    M("smooth union: F = m - k ln S (twice the bulge)", "cl/sdf.h",
      "r.f = m - 0.5f * sc->k * log(s2);", "r.f = m - sc->k * log(s2);",
      ("tests/test_glass.py -k field_matches_oracle",)),
    M("smooth union: weights over 2k instead of k", "cl/sdf.h",
      "float h = fmax(1.0f - (d - m) * inv_k, 0.0f);",
      "float h = fmax(1.0f - 0.5f * (d - m) * inv_k, 0.0f);",
      ("tests/test_glass.py -k field_matches_oracle",)),
    M("gradient bound: lip = 1 always", "cl/sdf.h",
      "r.lip = fmax(1.0f, 2.0f * s1o * inv_s - 1.0f);", "r.lip = 1.0f;",
      ("tests/test_glass.py -k gradient_bound",)),
    M("gradient: the nearest sphere's normal only", "cl/sdf.h",
      "r.grad = na + (g - s1 * na) * inv_s;", "r.grad = na;",
      ("tests/test_glass.py -k gradient_matches",)),
    M("a cell's list walked ahead tests its first sphere again and again", "cl/sdf.h",
      "e_ = en_; en_ = enn_; s4 = sn_;", "e_ = en_; en_ = enn_;",
      ("tests/test_glass.py -k prefetch",)),
    M("over-relaxation never falls back to the plain step", "cl/sdf.h",
      "        if (w > 1.0f && r + r_prev < step) {\n            t -= step - step / w;"
      "              /* back to the plain step: safe */",
      "        if (0) {\n            t -= step - step / w;"
      "              /* back to the plain step: safe */",
      ("tests/test_glass.py -k trace_finds", "tests/test_glass_dispatch.py -k over_relaxation")),
    # ------------------------------------------------------------ shared math (cl/common.h)
    M("pi = 3", "cl/common.h", "#define VR_PI 3.14159265358979f", "#define VR_PI 3.0f",
      (f"{OPTICS} -k opaque", "tests/test_phase.py")),
    M("1/(4 pi) is 1/(2 pi)", "cl/common.h", "#define VR_INV_4PI 0.0795774715459477f",
      "#define VR_INV_4PI 0.1591549430918953f", ("tests/test_phase.py",)),
    M("optical depths clamped at 8 (exp(-8) = 3e-4 reads as opaque)", "cl/common.h",
      "#define VR_TAU_MAX 80.0f", "#define VR_TAU_MAX 8.0f",
      (f"{THICK} -k exp_minus", "tests/test_extreme.py -k optically_thick or opaque_medium")),
    M("transmittance exp(-tau / 2)", "cl/common.h",
      "return isnan(tau) ? 0.0f : exp(-clamp(tau, 0.0f, VR_TAU_MAX));",
      "return isnan(tau) ? 0.0f : exp(-0.5f * clamp(tau, 0.0f, VR_TAU_MAX));",
      ("tests/test_render_volume.py -k slab_transmittance",)),
    M("random numbers in [0, 1/2)", "cl/common.h",
      "return (float)(h >> 8) * (1.0f / 16777216.0f);",
      "return (float)(h >> 9) * (1.0f / 16777216.0f);", ("tests/test_tracking.py",)),
    # ------------------------------------------------------------ camera (cl/camera.h)
    M("one sample per pixel off the pixel centre", "cl/camera.h",
      "return (float2)(0.5f, 0.5f);", "return (float2)(0.25f, 0.5f);",
      (f"{OPTICS} -k opaque",)),
    M("sample clamp at 1e20 instead of layout.SAMPLE_MAX", "cl/camera.h",
      "return fmin(select(L, (float3)(0.0f), isnan(L)), (float3)(VR_SAMPLE_MAX));",
      "return fmin(select(L, (float3)(0.0f), isnan(L)), (float3)(1e20f));",
      ("tests/test_extreme.py -k glass_knobs or volume_knobs or texels_beyond",)),
    # ------------------------------------------------------------ phase (cl/phase.h)
    M("HG: (1 - g) for (1 - g^2)", "cl/phase.h",
      "return VR_INV_4PI * (1.0f - g * g) / (denom * sqrt(denom));",
      "return VR_INV_4PI * (1.0f - g) / (denom * sqrt(denom));", ("tests/test_phase.py",)),
    M("HG: denominator to the power 1 for 3/2", "cl/phase.h",
      "return VR_INV_4PI * (1.0f - g * g) / (denom * sqrt(denom));",
      "return VR_INV_4PI * (1.0f - g * g) / denom;", ("tests/test_phase.py",)),
    M("HG sampling: mirrored (backward for g > 0)", "cl/phase.h",
      "return clamp((1.0f + g * g - s * s) / (2.0f * g), -1.0f, 1.0f);",
      "return clamp(-(1.0f + g * g - s * s) / (2.0f * g), -1.0f, 1.0f);",
      ("tests/test_phase.py -k sampling",)),
    M("isotropic sampling: forward hemisphere only", "cl/phase.h",
      "return clamp(2.0f * u - 1.0f, -1.0f, 1.0f);", "return clamp(u, -1.0f, 1.0f);",
      ("tests/test_phase.py -k sampling", "tests/test_path.py -k furnace")),
    M("sampled azimuth over half a turn", "cl/phase.h",
      "float st = sqrt(fmax(1.0f - mu * mu, 0.0f)), phi = 2.0f * VR_PI * u;",
      "float st = sqrt(fmax(1.0f - mu * mu, 0.0f)), phi = VR_PI * u;",
      ("tests/test_phase.py -k sampling", "tests/test_path.py")),
    M("phase mixture weights swapped", "cl/phase.h",
      "return ph.z * vr_hg(mu, ph.x) + (1.0f - ph.z) * vr_hg(mu, ph.y);",
      "return (1.0f - ph.z) * vr_hg(mu, ph.x) + ph.z * vr_hg(mu, ph.y);",
      ("tests/test_phase.py",)),
    M("phase sampling picks the lobes the wrong way round", "cl/phase.h",
      "float g = u0 < ph.z ? ph.x : ph.y;", "float g = u0 < ph.z ? ph.y : ph.x;",
      ("tests/test_phase.py -k sampling",)),
    # ------------------------------------------------------------ environment (cl/env.h)
    M("env map: u from atan2(x, z) (the centre looks along +z)", "cl/env.h",
      "inline float3 vr_env_map(__global const float4* env, int w, int h, float3 d)\n{\n"
      "    float u = 0.5f + atan2(d.x, -d.z) * (0.5f / VR_PI);",
      "inline float3 vr_env_map(__global const float4* env, int w, int h, float3 d)\n{\n"
      "    float u = 0.5f + atan2(d.x, d.z) * (0.5f / VR_PI);",
      ("tests/test_env.py -k lookup", f"{OPTICS} -k closed_form")),
    M("env map: v from acos(-y) (upside down)", "cl/env.h",
      "    float u = 0.5f + atan2(d.x, -d.z) * (0.5f / VR_PI);\n"
      "    float v = acos(clamp(d.y, -1.0f, 1.0f)) * (1.0f / VR_PI);\n"
      "    if (!(isfinite(u) && isfinite(v)))\n        return (float3)(0.0f);\n"
      "    float fx",
      "    float u = 0.5f + atan2(d.x, -d.z) * (0.5f / VR_PI);\n"
      "    float v = acos(clamp(-d.y, -1.0f, 1.0f)) * (1.0f / VR_PI);\n"
      "    if (!(isfinite(u) && isfinite(v)))\n        return (float3)(0.0f);\n"
      "    float fx",
      ("tests/test_env.py -k lookup", f"{OPTICS} -k closed_form")),
    M("env pdf: 4 pi^2 for 2 pi^2", "cl/env.h",
      "return p * (float)(w * h) / (2.0f * VR_PI * VR_PI * st);",
      "return p * (float)(w * h) / (4.0f * VR_PI * VR_PI * st);",
      (f"{ENVS}", "tests/test_env.py -k map_sampling")),
    M("env sampling: theta = v pi / 2", "cl/env.h",
      "float phi = (u - 0.5f) * (2.0f * VR_PI), theta = v * VR_PI;",
      "float phi = (u - 0.5f) * (2.0f * VR_PI), theta = v * VR_PI * 0.5f;", (f"{ENVS}",)),
    M("env sampling: every sample at its texel's centre row", "cl/env.h",
      "float fv = (u0 - cdf[i]) / fmax(cdf[i + 1] - cdf[i], 1e-30f);", "float fv = 0.5f;",
      (f"{ENVS}",)),
    # ------------------------------------------------------------ host sampling weights
    M("env weights without sin(theta) (the issue's volume.py:219)", "volrender/environment.py",
      "    return m * np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None]", "    return m",
      (f"{ENVS}", "tests/test_env.py -k map_sampling")),
    M("env weights: red instead of luminance", "volrender/environment.py",
      "lum = np.maximum(t[..., :3] @ np.array([0.2126, 0.7152, 0.0722]), 0.0)",
      "lum = np.maximum(t[..., 0], 0.0)", (f"{ENVS}",)),
    M("env weights: no maximum over the neighbours in u", "volrender/environment.py",
      "m = np.maximum(lum, np.maximum(np.roll(lum, 1, axis=1), np.roll(lum, -1, axis=1)))",
      "m = lum", (f"{ENVS}",)),
    M("env CDF: rows not normalised by the total", "volrender/environment.py",
      "row_cdf = np.concatenate([[0.0], np.cumsum(rows)]) / (total if total > 0 else 1.0)",
      "row_cdf = np.concatenate([[0.0], np.cumsum(rows)]) / (2 * total if total > 0 else 1.0)",
      (f"{ENVS}",)),
    M("tracking majorant from the smallest sigma_t scale", "volrender/volume.py",
      "mu = settings.density_scale * max(settings.sigma_t_scale) * np.asarray(bricks.majorant, np.float64)",
      "mu = settings.density_scale * min(settings.sigma_t_scale) * np.asarray(bricks.majorant, np.float64)",
      (f"{DEPTH} -k tracked", "tests/test_path.py -k coloured")),
    M("emission-only bricks get no tracking rate", "volrender/volume.py",
      "mu = np.where(emits, np.maximum(mu, 1.0 / bricks.voxel_size), mu)", "mu = mu",
      ("tests/test_tracking.py -k emission",)),
    M("march steps in voxels taken as world units", "volrender/volume.py",
      "step=settings.step * vs, shadow_step=settings.shadow_step * vs,",
      "step=settings.step, shadow_step=settings.shadow_step * vs,",
      ("tests/test_extreme.py -k voxel_size",)),
    M("unwritable output folders accepted", "volrender/image.py",
      "    if not os.access(parent, os.W_OK | os.X_OK):", "    if False:",
      ("tests/test_image.py -k unwritable",)),
    M("read-only outputs accepted (then replaced)", "volrender/atomic.py",
      "    if not os.access(real, os.W_OK):", "    if False:",
      ("tests/test_image.py -k read_only",)),
    M("glass absorption times the material unit", "volrender/glass.py",
      "absorption=[*(np.asarray(settings.absorption) / unit), 0]",
      "absorption=[*(np.asarray(settings.absorption) * unit), 0]", (f"{OPTICS} -k ior_one",)),
    M("glass glow not per material unit", "volrender/glass.py",
      "glow=settings.glow / unit,", "glow=settings.glow,", (f"{OPTICS} -k ior_one",)),
    # ------------------------------------------------------------ volumes: the march
    M("march depth x2", "cl/render_volume.cl",
      "                dsum += w * t;", "                dsum += 2.0f * w * t;",
      (f"{DEPTH} -k marched",)),
    M("march depth weights without the transmittance", "cl/render_volume.cl",
      "float w = vr_spec_mean(T * a);", "float w = vr_spec_mean(a);", (f"{DEPTH} -k marched",)),
    M("chromatic march depth from the red channel only", "cl/render_volume.cl",
      "float w = vr_spec_mean(T * a);", "float w = vr_spec_max(T * a);", (f"{DEPTH} -k marched",)),
    M("march emission: dt for the step's integral of T", "cl/render_volume.cl",
      "VrSpec len = select(a / sigma_t, (VrSpec)(dt), tau <= 1e-4f);", "VrSpec len = dt;",
      ("tests/test_render_volume.py -k emission",)),
    M("march in-scattering without the step's opacity", "cl/render_volume.cl",
      "L += T * a * VR_ALBEDO(vp) * S;", "L += T * VR_ALBEDO(vp) * S * vp->step;",
      ("tests/test_render_volume.py -k slab",)),
    M("march stops at T < 0.1", "cl/render_volume.cl",
      "#define VR_T_CUTOFF 1e-5f", "#define VR_T_CUTOFF 1e-1f",
      ("tests/test_render_volume.py -k slab or sphere", "tests/test_extreme.py -k opaque")),
    M("light phase at -mu (the flipped convention)", "cl/march.h",
      "sum += vr_phase(dot(prop, wo), vp->phase) * tr * lights[i].radiance.xyz / atten;",
      "sum += vr_phase(dot(prop, -wo), vp->phase) * tr * lights[i].radiance.xyz / atten;",
      ("tests/test_render_volume.py -k silver or slab",)),
    M("shadow march stops at tau 2.5", "cl/structs.h",
      "#define VR_SHADOW_TAU_STOP 25.0f", "#define VR_SHADOW_TAU_STOP 2.5f",
      (f"{THICK} -k exp_minus", "tests/test_render_volume.py -k slab")),
    M("octave bands gain 10% per band (energy not conserved)", "cl/march.h",
      "VrSpec gain = (light ? vp->ms.x : 1.0f) * VR_ALBEDO(vp);",
      "VrSpec gain = (light ? vp->ms.x : 1.0f) * VR_ALBEDO(vp) * 1.1f;",
      ("tests/test_defaults.py -k furnace", "tests/test_octaves.py")),
    M("baked environment bands gain 10% per band (energy not conserved)", "cl/march.h",
      "VrSpec gain = VR_ALBEDO(vp);", "VrSpec gain = VR_ALBEDO(vp) * 1.1f;",
      ("tests/test_defaults.py -k furnace", "tests/test_octaves.py")),
    M("env in-scattering: phase / pdf not divided (uniform env)", "cl/march.h",
      "    f = f / p0;                 /* phase sampling: p / pdf = 1 for octave 0 */",
      "    f = f;", ("tests/test_env.py", "tests/test_path.py -k depth_one")),
    M("env in-scattering: mixture density not halved", "cl/march.h",
      "pdf_mix = 0.5f * (p0 + pdf_env);", "pdf_mix = p0 + pdf_env;",
      ("tests/test_env.py -k thin_slab",)),
    # ------------------------------------------------------------ volumes: track and path
    M("path/track depth x2", "cl/path_volume.cl",
      "acc.depth += sg.tc;", "acc.depth += 2.0f * sg.tc;",
      (f"{DEPTH} -k tracked", "tests/test_tracking.py", "tests/test_path.py",
       "tests/test_launch.py")),
    M("path alpha from the largest channel's transmittance", "cl/path_volume.cl",
      "acc.alpha += 1.0f - vr_spec_mean(sg.w);", "acc.alpha += 1.0f - vr_spec_max(sg.w);",
      (f"{DEPTH} -k tracked",)),
    M("path light phase at +mu", "cl/path_volume.cl",
      "Lk += vr_phase(dot(prop, -din), vp->phase) * tr * lights[i].radiance.xyz / atten;",
      "Lk += vr_phase(dot(prop, din), vp->phase) * tr * lights[i].radiance.xyz / atten;",
      ("tests/test_tracking.py -k shadows",)),
    M("path roulette without dividing by the survival probability", "cl/path_volume.cl",
      "                beta /= q;", "                beta /= 1.0f;",
      ("tests/test_path.py -k furnace",)),
    M("path roulette survival cap 1 instead of 0.95", "cl/path_volume.cl",
      "#define VR_RR_MAX 0.95f", "#define VR_RR_MAX 1.0f",
      ("tests/test_path.py",),
      note="equivalent: q = min(max beta, cap) stays a valid survival probability and beta "
           "/ q keeps every estimate unbiased; the cap only trades variance for time"),
    M("path env map: MIS weight of the light sample without r", "cl/path_volume.cl",
      "Lk += (r / (1.0f + r * r)) * tr * vr_env_radiance(vp, env, we);",
      "Lk += (1.0f / (1.0f + r * r)) * tr * vr_env_radiance(vp, env, we);",
      (f"{ENVS} -k track",)),
    M("path env map: the phase-sampled walk not MIS-weighted", "cl/path_volume.cl",
      "                mis = 1.0f / (1.0f + r * r);", "                mis = 1.0f;",
      (f"{ENVS} -k track",)),
    M("ratio tracking at half the extinction", "cl/track.h",
      "w *= 1.0f - fmin(sigma * VR_EXTINCTION(vp) / k.mu, 1.0f);",
      "w *= 1.0f - fmin(0.5f * sigma * VR_EXTINCTION(vp) / k.mu, 1.0f);",
      ("tests/test_tracking.py -k shadows",)),
    M("tentative collisions at twice the majorant", "cl/track.h",
      "float tn = k->t - log(1.0f - u) / k->mu;", "float tn = k->t - log(1.0f - u) / (2.0f * k->mu);",
      ("tests/test_tracking.py -k alpha", f"{DEPTH} -k tracked")),
    M("stiff media: bulk optical depth without the 1/2 of the trapezoid", "cl/track.h",
      "VrSpec tau = 0.5f * (sigma + sigma1) * k.bulk * VR_EXTINCTION(vp);",
      "VrSpec tau = (sigma + sigma1) * k.bulk * VR_EXTINCTION(vp);",
      (f"{THICK} -k stiff", "tests/test_tracking.py -k stiff")),
    M("stiff media: bulk emission read at the interval's start (the bug fixed in issue #26)",
      "cl/track.h",
      "            if (k.bulk > 0.0f) {\n                /* the emission linear across the interval",
      "            if (0) {\n                /* the emission linear across the interval",
      (f"{THICK} -k stiff",)),
    M("spectral tracking: weight without the null-collision history", "cl/track.h",
      "out->wt = wnull * ratio_c * VR_ALBEDO(vp) / P;", "out->wt = ratio_c * VR_ALBEDO(vp) / P;",
      ("tests/test_path.py -k coloured",)),
    M("spectral tracking: no history (P = mean ratio at every point)", "cl/track.h",
      "                wnull *= (1.0f - ratio_c) / (1.0f - P);", "",
      (f"{DEPTH} -k tracked", "tests/test_path.py -k coloured")),
    M("ratio-weight roulette threshold 0.5", "cl/track.h",
      "#define VR_RR_W 0.1f", "#define VR_RR_W 0.5f", ("tests/test_tracking.py",),
      note="equivalent: Russian roulette of a weight w below the threshold survives with "
           "probability w / VR_RR_W at weight VR_RR_W, unbiased for any threshold"),
    M("--no-shadows also drops the environment's attenuation (march)", "cl/march.h",
      "VrSpec f = p0 * vr_transmit(vr_march_tau(g, vp, p, dl, INFINITY, u3, VR_SHADOW_TAU_STOP));",
      "VrSpec f = p0 * vr_transmit(vr_shadow_tau(g, vp, p, dl, INFINITY, u3, VR_SHADOW_TAU_STOP));",
      ("tests/test_render_volume.py -k feature_without",)),
    # ------------------------------------------------------------ lights, grid, blackbody
    M("volume point lights fall off as 1/r", "cl/lights.h",
      "*atten = fmax(r2, vp->point_r2_min);", "*atten = fmax(r, vp->point_r2_min);",
      ("tests/test_render_volume.py -k inverse_square",)),
    M("sun shadow rays towards the propagation direction", "cl/lights.h",
      "*dl = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, -d);",
      "*dl = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, d);",
      ("tests/test_render_volume.py -k with_shadows",)),
    M("trilinear: x and y fractions swapped", "cl/volume.h",
      "return mix(mix(c00, c01, f.y), mix(c10, c11, f.y), f.x);",
      "return mix(mix(c00, c01, f.x), mix(c10, c11, f.x), f.y);",
      ("tests/test_render_volume.py -k transform or sphere", f"{DEPTH} -k marched")),
    M("Planck's law with lambda^4", "volrender/blackbody.py",
      "return 2 * _H * _C ** 2 / (lam ** 5 * np.expm1(_H * _C / (lam * _K * t)))",
      "return 2 * _H * _C ** 2 / (lam ** 4 * np.expm1(_H * _C / (lam * _K * t)))",
      ("tests/test_blackbody.py",)),
    M("blackbody colours white-balanced to nothing", "volrender/blackbody.py",
      "v = np.clip(linear_rec709(kelvin) / _WHITE, 0.0, None)",
      "v = np.clip(linear_rec709(kelvin), 0.0, None)", ("tests/test_blackbody.py",)),
    M("blackbody table in T instead of 1/T (kernel index)", "volrender/volume.py",
      "bb_a = (n - 1) / (1.0 / blackbody.T_MIN - 1.0 / blackbody.T_MAX)",
      "bb_a = (n - 1) / (1.0 / blackbody.T_MIN - 1.0 / blackbody.T_MAX) * 0.5",
      ("tests/test_blackbody.py -k kernel or temperature",)),
    M("blackbody table read without interpolation", "cl/volume.h",
      "float4 c = mix(bb[i], bb[i + 1], f - (float)i);", "float4 c = bb[i];",
      ("tests/test_blackbody.py -k kernel",)),
    M("temperature-grid emission without emission_scale", "cl/volume.h",
      "return vp->emission_scale * vr_blackbody(bb, vp, kelvin);",
      "return vr_blackbody(bb, vp, kelvin);", ("tests/test_blackbody.py -k temperature",)),
    # ------------------------------------------------------------ issue 39: generic parameters
    # constants swapped for neighbours, parameters at the wrong end of an interval, weights
    # dropped where they are 1 at the defaults; tests/test_generic_params.py
    M("XYZ -> Rec.709: a row entry swapped with its neighbour", "volrender/blackbody.py",
      "[[3.2404542, -1.5371385, -0.4985314],", "[[3.2404542, -0.4985314, -1.5371385],",
      (f"{GEN} -k xyz_to_rec709",)),
    M("XYZ -> Rec.709: the blue row's first two entries swapped", "volrender/blackbody.py",
      "[0.0556434, -0.2040259, 1.0572252]]", "[-0.2040259, 0.0556434, 1.0572252]]",
      (f"{GEN} -k xyz_to_rec709",)),
    M("Rec.709 luminance weights: green and blue swapped", "volrender/blackbody.py",
      "REC709_Y = np.array([0.2126, 0.7152, 0.0722])", "REC709_Y = np.array([0.2126, 0.0722, 0.7152])",
      (f"{GEN} -k xyz_to_rec709",)),
    M("env weights: Rec.709 green and blue weights swapped", "volrender/environment.py",
      "lum = np.maximum(t[..., :3] @ np.array([0.2126, 0.7152, 0.0722]), 0.0)",
      "lum = np.maximum(t[..., :3] @ np.array([0.2126, 0.0722, 0.7152]), 0.0)",
      (f"{GEN} -k environment_luminance",)),
    M("sRGB: gamma 2.2", "volrender/image.py", "1.0 / 2.4) - 0.055)", "1.0 / 2.2) - 0.055)",
      (f"{GEN} -k srgb",)),
    M("sRGB: linear segment to 0.003", "volrender/image.py",
      "np.where(v <= 0.0031308, 12.92 * v,", "np.where(v <= 0.003, 12.92 * v,",
      (f"{GEN} -k srgb",)),
    M("sRGB: 1.05 for 1.055", "volrender/image.py", "1.055 * np.power(", "1.05 * np.power(",
      (f"{GEN} -k srgb",)),
    M("sRGB: offset 0.05 for 0.055", "volrender/image.py", "1.0 / 2.4) - 0.055)",
      "1.0 / 2.4) - 0.05)", (f"{GEN} -k srgb",)),
    M("full model: an internal reflection not weighted by reflectivity", "cl/shade_glass.h",
      "rb.thr = thr * (e.fr * gp->reflectivity);",
      "rb.thr = thr * (inside ? e.fr : e.fr * gp->reflectivity);", (f"{GEN} -k axis",)),
    M("full model: reflections not weighted by reflectivity", "cl/shade_glass.h",
      "rb.thr = thr * (e.fr * gp->reflectivity);", "rb.thr = thr * e.fr;", (f"{GEN} -k axis",)),
    M("full model: the refracted share 1 - F reflectivity", "cl/shade_glass.h",
      "tb.thr = thr * (1.0f - e.fr);", "tb.thr = thr * (1.0f - e.fr * gp->reflectivity);",
      (f"{GEN} -k axis",)),
    M("full model: the exit's internal reflection dropped (checked directly)", "cl/shade_glass.h",
      "rb.thr = thr * (e.fr * gp->reflectivity);",
      "rb.thr = inside ? (float3)(0.0f) : thr * (e.fr * gp->reflectivity);", (f"{GEN} -k axis",)),
    M("fast model: the exit reflection kept", "cl/shade_glass.h",
      "        if (!inside)\n            rgb += thr * (e.fr * gp->reflectivity) * glass_env(gp, env, e.refl);",
      "        rgb += thr * (e.fr * gp->reflectivity) * glass_env(gp, env, e.refl);",
      (f"{GEN} -k axis",)),
    M("fast model: the outer reflection not weighted by reflectivity", "cl/shade_glass.h",
      "rgb += thr * (e.fr * gp->reflectivity) * glass_env(gp, env, e.refl);",
      "rgb += thr * e.fr * glass_env(gp, env, e.refl);", (f"{GEN} -k axis",)),
    M("octaves: a band's phase at its end, not its middle", "cl/march.h",
      "float ck = pow(vp->ms.y, u - 0.5f * du);", "float ck = pow(vp->ms.y, u);",
      (f"{GEN} -k octave_bands",)),
    M("octaves: a band's phase at its start", "cl/march.h",
      "float ck = pow(vp->ms.y, u - 0.5f * du);", "float ck = pow(vp->ms.y, u - du);",
      (f"{GEN} -k octave_bands",)),
    M("octaves: A_k with (k + 1) / (N - 1)", "cl/march.h",
      "exp((float)k * (1.0f / (float)(VR_MS_OCTAVES - 1)) * ln_a)",
      "exp((float)(k + 1) * (1.0f / (float)(VR_MS_OCTAVES - 1)) * ln_a)",
      (f"{GEN} -k octave_bands",)),
    M("octaves: band spacing 1 / N (the last band short of A_inf)", "cl/march.h",
      "exp((float)k * (1.0f / (float)(VR_MS_OCTAVES - 1)) * ln_a)",
      "exp((float)k * (1.0f / (float)VR_MS_OCTAVES) * ln_a)",
      (f"{GEN} -k octave_bands",)),
    M("octaves: light bands without the albedo", "cl/march.h",
      "VrSpec gain = (light ? vp->ms.x : 1.0f) * VR_ALBEDO(vp);",
      "VrSpec gain = light ? (VrSpec)(vp->ms.x) : VR_ALBEDO(vp);",
      (f"{GEN} -k octave_bands",)),
    M("octaves: every band against band 0 (no telescoping)", "cl/march.h",
      "        sum += gain * ph * (tk - prev);\n        prev = tk;",
      "        sum += gain * ph * (tk - prev);", (f"{GEN} -k octave_bands",)),
    M("octaves: chromatic decay of the red channel for all", "cl/march.h",
      "float3 ln_a = vp->ms_decay.xyz;", "float3 ln_a = (float3)(vp->ms_decay.x);",
      (f"{GEN} -k octave_bands",)),
    M("octave decay: mean cosine of the first lobe only", "volrender/volume.py",
      "return w * g1 + (1.0 - w) * g2", "return g1", (f"{GEN} -k octave_bands",)),
    M("octave decay: sqrt(1 - albedo) without the 3", "volrender/volume.py",
      "np.sqrt(3.0 * np.clip(1.0 - alb, 0.0, 1.0) * one_g)",
      "np.sqrt(np.clip(1.0 - alb, 0.0, 1.0) * one_g)", (f"{GEN} -k octave_bands",)),
    M("octave decay: D read from G's slot", "volrender/volume.py",
      "d = (settings.ms_octave_scales or MS_SCALES)[0]", "d = (settings.ms_octave_scales or MS_SCALES)[1]",
      (f"{GEN} -k octave_bands",)),
    M("octave params: G and C swapped", "volrender/volume.py",
      "ms=[*octave_scales(settings, bricks)[1:], 0.0,",
      "ms=[*octave_scales(settings, bricks)[2:0:-1], 0.0,",
      (f"{GEN} -k octave_bands",)),
    M("march env: phase samples pick the lobe from u0 unscaled (always lobe 1)", "cl/march.h",
      "w = vr_phase_sample(vp->phase, d, 2.0f * u0, u1, u2);",
      "w = vr_phase_sample(vp->phase, d, u0, u1, u2);", (f"{GEN} -k mixed_phase",)),
    M("march env: the mixture density with the first lobe only", "cl/march.h",
      "pdf_mix = 0.5f * (p0 + pdf_env);",
      "pdf_mix = 0.5f * (vr_hg(dot(w, d), vp->phase.x) + pdf_env);", (f"{GEN} -k mixed_phase",)),
    M("march env: a quarter of the samples from the phase", "cl/march.h",
      "if (u0 < 0.5f)", "if (u0 < 0.25f)", (f"{GEN} -k mixed_phase",)),
    M("path env map: the map sample's phase with lobe 1 only", "cl/path_volume.cl",
      "float ph = vr_phase(dot(we, din), vp->phase);",
      "float ph = vr_hg(dot(we, din), vp->phase.x);", (f"{GEN} -k tracking_under",)),
    M("path env map: the walk's MIS weight with lobe 1's density", "cl/path_volume.cl",
      "float ph = vr_phase(dot(wn, din), vp->phase);",
      "float ph = vr_hg(dot(wn, din), vp->phase.x);", (f"{GEN} -k tracking_under",),
      note="a real bias, but small: the weight only shifts light between the map sample and "
           "the walk, which see the same radiance (measured with this test's map and phase: "
           "-1.1 % of the pixel, -1.3e-3 against a standard error of 1.3e-3; resolving it "
           "takes ~25x the samples of a suite test)"),
    M("march alpha from the largest channel's transmittance", "cl/render_volume.cl",
      "acc.alpha += 1.0f - vr_spec_mean(T);", "acc.alpha += 1.0f - vr_spec_max(T);",
      (f"{GEN} -k alpha",)),
    M("march jitter: every sample at its step's middle", "cl/render_volume.cl",
      "            float t = t0 + ((float)k + u) * dt;\n            if (t >= t_end",
      "            float t = t0 + ((float)k + 0.5f) * dt;\n            if (t >= t_end",
      (f"{GEN} -k jitter",)),
    M("march jitter over half a step", "cl/render_volume.cl",
      "            float t = t0 + ((float)k + u) * dt;\n            if (t >= t_end",
      "            float t = t0 + ((float)k + 0.5f * u) * dt;\n            if (t >= t_end",
      (f"{GEN} -k jitter",)),
    M("cells: list threshold U + k/2", "cl/build_cells.cl",
      "a.thr = U + a.k + cb->pad;", "a.thr = U + 0.5f * a.k + cb->pad;",
      (f"{GEN} -k support_cells",)),
    M("cells: list threshold without the rounding pad", "cl/build_cells.cl",
      "a.thr = U + a.k + cb->pad;", "a.thr = U + a.k;", (f"{GEN} -k support_cells",),
      note="not visible at 1e-4: the pad (1e-5 of the extent) covers float32 rounding of "
           "lo_i and U (~1e-7 relative); a sphere 1e-4 inside the threshold is listed "
           "without it, and one within the rounding of it is a coin toss no test can pin"),
    M("cells: core threshold M (the nearest lo)", "cl/build_cells.cl",
      "a.core = U + cb->pad;", "a.core = M + cb->pad;", (f"{GEN} -k support_cells",)),
    M("cells: U from lo_i (the nearest distance, not the farthest)", "cl/build_cells.cl",
      "                m = fmin(m, a);\n                u = fmin(u, b);",
      "                m = fmin(m, a);\n                u = fmin(u, a);",
      (f"{GEN} -k support_cells",)),
    M("cells: the cell of a point rounded, not floored", "cl/cells.h",
      "float3 g = floor((x - sc->grid_lo) * sc->inv_cell);",
      "float3 g = round((x - sc->grid_lo) * sc->inv_cell);", (f"{GEN} -k own_cells_list",)),
]


def copy_tree(dst: Path):
    """The working tree's files (tracked and untracked, not ignored) into dst."""
    out = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT,
                         check=True, capture_output=True).stdout
    for rel in filter(None, out.decode().split("\0")):
        src = ROOT / rel
        if src.is_file():
            (dst / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst / rel)


def run_tests(copy: Path, invocation: str, timeout: float):
    """(rc, output, seconds) of one pytest invocation in the copy."""
    env = dict(os.environ, PYTHONPATH=str(copy), PYTHONDONTWRITEBYTECODE="1")
    shared = ROOT.parent / "shared" / "data"
    if "VOLRENDER_SHARED_DATA" not in env and shared.is_dir():
        env["VOLRENDER_SHARED_DATA"] = str(shared)
    args = shlex.split(invocation)
    if "-k" in args:                       # "-k a or b": the rest of the line is the expression
        i = args.index("-k")
        args = args[:i] + ["-k", " ".join(args[i + 1:])]
    cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", *args]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, cwd=copy, env=env, capture_output=True, text=True,
                           timeout=timeout)
        rc, out = p.returncode, p.stdout + p.stderr
    except subprocess.TimeoutExpired as e:
        rc, out = -1, f"timeout after {timeout:g} s\n{e.stdout or ''}"
    return rc, out, time.perf_counter() - t0


def first_failure(out: str) -> str:
    m = re.search(r"^FAILED (\S+)", out, re.M)
    if not m:
        return ""
    return m.group(1).replace("tests/", "")


def where(text: str, snippet: str) -> int:
    return text[:text.index(snippet)].count("\n") + 1


def run_mutant(copy: Path, m: Mutant, timeout: float) -> dict:
    path = copy / m.file
    text = path.read_text()
    count = text.count(m.old)
    row = {"mutant": m, "line": None, "status": "", "detail": "", "seconds": 0.0}
    if count == 0:
        row.update(status="stale", detail="snippet not found")
        return row
    if count > 1:
        row.update(status="ambiguous", detail=f"snippet found {count} times")
        return row
    row["line"] = where(text, m.old)
    path.write_text(text.replace(m.old, m.new))
    try:
        for inv in m.tests:
            rc, out, sec = run_tests(copy, inv, timeout)
            row["seconds"] += sec
            if rc == 0:
                continue
            if "OpenCL build of" in out or "BuildError" in out:
                row.update(status="broken", detail="the mutant does not build")
            elif rc == 1:
                row.update(status="killed", detail=first_failure(out) or inv)
            else:
                tail = out.strip().splitlines()[-1:] or [""]
                row.update(status="error", detail=f"pytest rc {rc} on `{inv}`: {tail[0][:120]}")
            return row
        row.update(status="survived", detail=m.note or "no named test failed")
        return row
    finally:
        path.write_text(text)


def table(rows, kept=None) -> str:
    """The markdown table of `rows`; with `kept` (name -> (where, result, detail) of a
    table written before), every mutant of the list in order, those not run now from it."""
    if kept is not None:
        ran = {r["mutant"].name: r for r in rows}
        rows = [ran.get(m.name) or {"mutant": m, "kept": kept.get(m.name)} for m in MUTANTS]
    counts = {}
    lines = ["| # | mutant | where | result | killed by / why |", "|---|---|---|---|---|"]
    for i, r in enumerate(rows, 1):
        m = r["mutant"]
        if "kept" in r:
            if r["kept"] is None:
                raise SystemExit(f"{m.name!r} was never run: run it (-k) before --write")
            loc, status, detail = r["kept"]
        else:
            status = r["status"]
            loc = f"`{m.file}:{r['line']}`" if r["line"] else f"`{m.file}`"
            detail = r["detail"].replace("|", "\\|")
            if status == "killed":
                detail = f"`{detail}`"
        counts[status] = counts.get(status, 0) + 1
        lines.append(f"| {i} | {m.name} | {loc} | {status} | {detail} |")
    summary = ", ".join(f"{counts[k]} {k}" for k in
                        ("killed", "survived", "stale", "ambiguous", "broken", "error") if k in counts)
    return "\n".join(lines) + f"\n\n{len(rows)} mutants: {summary}.\n"


def doc_rows() -> dict:
    """name -> (where, result, detail) of the table in docs/testing.md."""
    doc = DOC.read_text()
    if BEGIN not in doc:
        return {}
    out = {}
    for line in doc.split(BEGIN, 1)[1].split(END, 1)[0].splitlines():
        cells = re.split(r"(?<!\\) \| ", line.strip().strip("|").strip())
        if len(cells) == 5 and cells[0].isdigit():
            out[cells[1]] = (cells[2], cells[3], cells[4])
    return out


def write_doc(text: str):
    doc = DOC.read_text()
    if BEGIN not in doc or END not in doc:
        raise SystemExit(f"{DOC} has no {BEGIN} ... {END} section")
    head, rest = doc.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    DOC.write_text(f"{head}{BEGIN}\n{text}{END}{tail}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-k", dest="match", action="append", default=[],
                    help="only mutants whose name contains this (repeat: any of them)")
    ap.add_argument("--from", dest="start", type=int, default=1, metavar="N",
                    help="only mutants N, N+1, ... of the list (1-based), e.g. the newest")
    ap.add_argument("--list", action="store_true", help="list the mutants and whether each "
                    "snippet is found, run nothing")
    ap.add_argument("--write", action="store_true", help="write the table to docs/testing.md")
    ap.add_argument("--no-baseline", action="store_true", help="skip the unmutated run")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per pytest run")
    args = ap.parse_args(argv)
    mutants = [m for m in MUTANTS[max(args.start, 1) - 1:]
               if not args.match or any(k.lower() in m.name.lower() for k in args.match)]
    if args.list:
        for i, m in enumerate(mutants, 1):
            n = (ROOT / m.file).read_text().count(m.old)
            state = {0: "STALE", 1: "ok"}.get(n, f"AMBIGUOUS x{n}")
            print(f"{i:3d} {state:10s} {m.file:24s} {m.name}")
        return 0
    with tempfile.TemporaryDirectory(prefix="volrender-mutants-") as tmp:
        copy = Path(tmp)
        copy.chmod(0o755)     # tests that drop to `nobody` import the copy's volrender too
        copy_tree(copy)
        if not args.no_baseline:
            for inv in dict.fromkeys(inv for m in mutants for inv in m.tests):
                rc, out, sec = run_tests(copy, inv, args.timeout)
                print(f"baseline {'ok  ' if rc == 0 else 'FAIL'} {sec:6.1f} s  {inv}", flush=True)
                if rc != 0:
                    print(out[-3000:])
                    raise SystemExit("the unmutated tests fail: fix them first")
        rows = []
        for i, m in enumerate(mutants, 1):
            row = run_mutant(copy, m, args.timeout)
            rows.append(row)
            print(f"{i:3d}/{len(mutants)} {row['status']:9s} {row['seconds']:6.1f} s  {m.name}"
                  f"  [{row['detail']}]", flush=True)
    subset = len(rows) < len(MUTANTS)
    text = table(rows, doc_rows() if subset and args.write else None)
    print("\n" + text)
    if args.write:
        write_doc(text)
        print(f"written to {DOC.relative_to(ROOT)}")
    return 0 if all(r["status"] in ("killed",) or (r["status"] == "survived" and r["mutant"].note)
                    for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
