"""The image-quality metrics of `make bench-render-quality` (scripts/bench_render_quality.py) on
cases with a known answer: PSNR of a constant offset, SSIM of an image with itself, of two
constant images (its luminance term alone), and its order under growing noise."""

import importlib.util
import sys

import numpy as np
import pytest

from conftest import REPO

spec = importlib.util.spec_from_file_location(
    "bench_render_quality", REPO / "scripts" / "bench_render_quality.py"
)
quality = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = quality  # its dataclass looks the module up while it loads
spec.loader.exec_module(quality)


def test_psnr_of_a_constant_offset():
    image = np.full((20, 30, 3), 100, np.uint8)
    # MSE 4 → 10 log10(255² / 4)
    assert quality.psnr(image + 2, image) == pytest.approx(10 * np.log10(255**2 / 4))
    assert quality.psnr(image, image) == float("inf")


def test_ssim_of_an_image_with_itself_is_one_and_symmetric():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    b = np.clip(a + rng.normal(0, 10, a.shape), 0, 255).astype(np.uint8)
    assert quality.ssim(a, a) == pytest.approx(1.0)
    assert quality.ssim(a, b) == pytest.approx(quality.ssim(b, a))


def test_ssim_of_two_constant_images_is_its_luminance_term():
    x, y = 100.0, 120.0
    c1 = (0.01 * 255) ** 2
    expected = (2 * x * y + c1) / (x * x + y * y + c1)  # no variance: the other terms are 1
    a = np.full((30, 30, 3), x, np.uint8)
    b = np.full((30, 30, 3), y, np.uint8)
    assert quality.ssim(a, b) == pytest.approx(expected, rel=1e-9)


def test_ssim_and_psnr_fall_as_noise_grows():
    rng = np.random.default_rng(1)
    reference = rng.integers(50, 200, (48, 48, 3)).astype(np.uint8)
    noisy = [
        np.clip(reference + rng.normal(0, sigma, reference.shape), 0, 255).astype(np.uint8)
        for sigma in (2, 8, 32)
    ]
    ssims = [quality.ssim(n, reference) for n in noisy]
    psnrs = [quality.psnr(n, reference) for n in noisy]
    assert ssims[0] > ssims[1] > ssims[2] and psnrs[0] > psnrs[1] > psnrs[2]
