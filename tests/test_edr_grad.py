"""EDR's fused training path (forward and backward numba kernels) against autograd through the
torch path, gradcheck, the float64 reference of the paper's equations, and a known answer."""

from __future__ import annotations

import pytest
import torch

from edr.representations import EDR
from edr.representations.edr_grad import FusedEDRFunction
from edr_reference import edr_reference

VARIANTS = [
    {},
    {"return_form": "log"},
    {"threshold": "hard"},
    {"half_lives": (1.0, 3.8), "beta": (1.0, 0.5), "nu_on": (0.05, 0.1), "nu_off": (0.05, 0.2)},
    {"half_lives": (1.0, 3.8), "combine": "sum"},
    {"half_lives": (1.0, 3.8), "combine": "sum", "return_form": "log", "threshold": "hard"},
    {"color": "gray"},
    {"half_lives": (1.0, 3.8), "bptt_window": 3},  # truncated backpropagation through time
]


def _clip(dtype: torch.dtype, channels: int = 3) -> torch.Tensor:
    torch.manual_seed(0)
    return (torch.rand(2, 7, channels, 5, 6, dtype=dtype) * 255).requires_grad_()


def _grads(edr: EDR, clip: torch.Tensor, weights: torch.Tensor) -> list[torch.Tensor]:
    clip = clip.detach().clone().requires_grad_()
    out = edr(clip)
    (out * weights).sum().backward()
    return [out.detach(), clip.grad, *(p.grad for p in edr.parameters())]


@pytest.mark.parametrize("variant", VARIANTS, ids=lambda v: ",".join(f"{k}={v[k]}" for k in v))
@pytest.mark.parametrize(("dtype", "tolerance"), [(torch.float64, 1e-6), (torch.float32, 2e-3)])
def test_fused_backward_equals_autograd_through_the_torch_path(variant, dtype, tolerance) -> None:
    """Events, the input's gradient and every parameter's (hard: the soft one's as surrogate).
    float32: relative 2e-3 (sums over 420 pixel-frames in another order)."""
    out_dtype = "float64" if dtype == torch.float64 else "float32"
    fused = EDR(learnable=True, out_dtype=out_dtype, **variant)
    torch_path = EDR(learnable=True, out_dtype=out_dtype, fast=False, **variant)
    clip = _clip(dtype)
    assert fused.trains_fused(clip) and not torch_path.trains_fused(clip)
    weights = torch.randn_like(fused(clip).detach())
    for got, want in zip(
        _grads(fused, clip, weights), _grads(torch_path, clip, weights), strict=True
    ):
        scale = want.abs().max().clamp_min(1.0)
        torch.testing.assert_close(got / scale, want / scale, rtol=0, atol=tolerance)


@pytest.mark.parametrize(("log_form", "sum_k"), [(False, False), (True, False), (False, True)])
def test_gradcheck_of_the_fused_function(log_form: bool, sum_k: bool) -> None:
    torch.manual_seed(1)
    intensity = (torch.rand(1, 5, 2, 4, dtype=torch.float64) * 200 + 1).requires_grad_()
    k = 2
    params = [
        torch.tensor([0.5, 0.17], dtype=torch.float64, requires_grad=True),  # alpha
        torch.tensor([1.0, 0.7], dtype=torch.float64, requires_grad=True),  # beta
        torch.full((1 if sum_k else k,), 1.02, dtype=torch.float64, requires_grad=True),  # on
        torch.full((1 if sum_k else k,), 0.98, dtype=torch.float64, requires_grad=True),  # off
    ]
    if log_form:  # a log response near 0: thresholds around it
        params[2].data.fill_(0.01)
        params[3].data.fill_(-0.01)

    def events(x, alpha, beta, on, off):
        return FusedEDRFunction.apply(x, alpha, beta, on, off, log_form, False, sum_k)

    assert torch.autograd.gradcheck(events, (intensity, *params), eps=1e-6, atol=1e-5)


@pytest.mark.parametrize("variant", VARIANTS[:6], ids=str)  # the reference has no window
def test_fused_training_forward_equals_the_papers_equations(variant) -> None:
    edr = EDR(learnable=True, out_dtype="float64", **variant)
    clip = _clip(torch.float64, channels=1)
    settings = {"half_lives": [3.8], "beta": [1.0], "nu_on": [0.05], "nu_off": [0.05],
                "threshold": "soft", "return_form": "ratio", "combine": "separate", "eps": 1.0,
                "color": "keep"}  # fmt: skip
    for key, value in variant.items():
        settings[key] = list(value) if isinstance(value, tuple) else value
    k = len(settings["half_lives"])
    for key in ("beta", "nu_on", "nu_off"):
        if len(settings[key]) == 1 and (key == "beta" or settings["combine"] != "sum"):
            settings[key] = settings[key] * k
    expected, _, _ = edr_reference(clip.detach().numpy(), **settings)
    # the layer's parameters are float32 (alpha, thresholds): agreement to their precision
    torch.testing.assert_close(edr(clip).detach(), torch.from_numpy(expected), rtol=1e-5, atol=1e-5)


def test_learning_recovers_a_half_life_from_a_wrong_start() -> None:
    """The known answer: fit a learnable EDR's events to a fixed EDR's (tau = 3.8) from
    tau = 1.0 on a moving pattern; the half-life converges to 3.8."""
    torch.manual_seed(0)
    base = torch.rand(1, 1, 1, 16, 16) * 200 + 20
    clip = torch.cat([torch.roll(base, shifts=i, dims=-1) for i in range(40)], dim=1)
    target = EDR(half_lives=(3.8,))(clip).detach()
    learner = EDR(half_lives=(1.0,), learnable=True)
    learner.beta.requires_grad_(False)
    learner.nu_on.requires_grad_(False)
    learner.nu_off.requires_grad_(False)
    optim = torch.optim.Adam([learner.log_tau], lr=0.05)
    for _ in range(150):
        loss = (learner(clip) - target).pow(2).mean()
        optim.zero_grad()
        loss.backward()
        optim.step()
    assert abs(learner.half_lives.item() - 3.8) < 0.05, learner.half_lives.item()


def test_the_gradient_study_writes_a_record_and_its_table(tmp_path, capsys) -> None:
    import json

    from edr.studies import edr_stability

    edr_stability.main(["--seeds", "2", "--steps", "2", "--size", "24", "--out-dir", str(tmp_path)])
    (record,) = tmp_path.glob("edr_gradients_*.json")
    settings = json.loads(record.read_text())["settings"]
    assert [(s["frames"], s["window"], s["parameterization"]) for s in settings] == [
        (t, w, p) for t in (60, 250) for w in (None, 10) for p in ("log", "bounded")
    ]
    assert all(r["first_grad_norm"] > 0 for s in settings for r in s["runs"])
    assert "| 250 | full | bounded | 2 |" in capsys.readouterr().out


def test_the_bounded_parameterization_starts_where_the_log_one_does_and_stays_in_range() -> None:
    clip = _clip(torch.float32, channels=1).detach()
    settings = {"half_lives": (1.0, 3.8), "beta": (1.0, 0.5), "nu_on": 0.1, "nu_off": 0.2}
    plain = EDR(learnable=True, **settings)
    bounded = EDR(learnable=True, parameterization="bounded", **settings)
    torch.testing.assert_close(bounded(clip), plain(clip), rtol=1e-4, atol=1e-4)
    assert {n for n, _ in bounded.named_parameters()} == {
        "tau_logit", "log_beta", "nu_on_logit", "nu_off_logit",
    }  # fmt: skip
    with torch.no_grad():  # pushed far: the bounded values stay in their ranges
        for name in ("tau_logit", "nu_on_logit", "nu_off_logit"):
            getattr(bounded, name).add_(8.0)
    values = bounded.settings_now()
    assert values["edr/tau_0"] <= 64 and 0 < values["edr/nu_off_0"] < 1 and values["edr/beta_0"] > 0
    bounded(clip).sum().backward()
    assert all(torch.isfinite(p.grad).all() for p in bounded.parameters())
    with pytest.raises(ValueError, match="bounded"):
        EDR(half_lives=(100.0,), learnable=True, parameterization="bounded")


def _best_threshold_accuracy(feature: torch.Tensor, labels: torch.Tensor) -> float:
    """The accuracy of the best rule ``feature > c`` over every cut ``c``."""
    order = labels[feature.argsort()]
    # cut after k samples: the first k say 0, the rest 1
    right = torch.cat([torch.zeros(1), (1 - order).cumsum(0)]) + torch.cat(
        [order.flip(0).cumsum(0).flip(0), torch.zeros(1)]
    )
    return float(right.max() / len(labels))


def test_learning_finds_the_one_timescale_that_separates_two_classes() -> None:
    """The known answer with a classifier: clips (random walks of intensity) are labelled by
    how much a fixed EDR with half-life 3.8 fires ON; a learnable EDR starting at half-life 1,
    whose ON activity a linear classifier reads, learns a half-life near 3.8 and separates the
    classes, which its starting half-life does not."""
    torch.manual_seed(0)
    clips = (120 + (torch.randn(192, 40, 1, 8, 8) * 8).cumsum(1)).clamp(5, 250)
    on = EDR(half_lives=(3.8,))(clips)[:, :, 0].mean((1, 2, 3))  # (B,) ON activity
    labels = (on > on.median()).float()
    student = EDR(half_lives=(1.0,), learnable=True)
    for fixed in (student.beta, student.nu_on, student.nu_off):
        fixed.requires_grad_(False)
    start = student(clips)[:, :, 0].mean((1, 2, 3)).detach()
    weights = torch.zeros(2, requires_grad=True)  # the classifier: scale and bias
    optim = torch.optim.Adam([{"params": [student.log_tau], "lr": 0.05},
                              {"params": [weights], "lr": 0.1}])  # fmt: skip
    for _ in range(150):
        activity = student(clips)[:, :, 0].mean((1, 2, 3))
        feature = (activity - activity.mean()) / (activity.std() + 1e-6)
        logits = 5 * weights[0] * feature + weights[1]
        loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, labels)
        optim.zero_grad()
        loss.backward()
        optim.step()
    assert _best_threshold_accuracy(start, labels) < 0.9  # half-life 1 does not separate them
    assert ((logits > 0).float() == labels).float().mean() > 0.97
    assert abs(student.half_lives.item() - 3.8) < 0.3, student.half_lives.item()
