"""The sinusoidal encoding (double-angle recurrence, hand-written backward) against its direct definition."""

import math

import pytest
import torch

from spotlessgs.models.nets import encoding_size, sinusoidal_encoding


def direct_encoding(x: torch.Tensor, frequencies: int) -> torch.Tensor:
    """[x, sin(2^k π x), cos(2^k π x) for k < F], one sin/cos call per band."""
    feats = [x]
    for k in range(frequencies):
        arg = (math.pi * 2.0**k) * x
        feats += [torch.sin(arg), torch.cos(arg)]
    return torch.cat(feats, dim=-1)


@pytest.mark.parametrize("frequencies", [0, 1, 6])
def test_values_match_the_direct_definition(frequencies):
    x = torch.linspace(-1.0, 1.0, 9 * 64, dtype=torch.float64).reshape(64, 9)
    out = sinusoidal_encoding(x, frequencies)
    assert out.shape == (64, encoding_size(9, frequencies))
    torch.testing.assert_close(out, direct_encoding(x, frequencies), rtol=0, atol=1e-12)
    # float32: the recurrence doubles the absolute error per band, 2^6 ulp at most.
    torch.testing.assert_close(sinusoidal_encoding(x.float(), frequencies), direct_encoding(x.float(), frequencies),
                               rtol=0, atol=5e-6)


def test_gradient_matches_autograd_of_the_direct_definition_for_any_leading_shape():
    gen = torch.Generator().manual_seed(3)
    x = (2 * torch.rand(4, 5, 3, generator=gen, dtype=torch.float64) - 1).requires_grad_()
    weights = torch.randn(4, 5, encoding_size(3, 4), generator=gen, dtype=torch.float64)
    (ours,) = torch.autograd.grad((sinusoidal_encoding(x, 4) * weights).sum(), x)
    (reference,) = torch.autograd.grad((direct_encoding(x, 4) * weights).sum(), x)
    torch.testing.assert_close(ours, reference, rtol=1e-10, atol=1e-10)
    assert torch.autograd.gradcheck(lambda t: sinusoidal_encoding(t, 3), (x[0].detach().requires_grad_(),))


def test_negative_frequencies_are_refused():
    with pytest.raises(ValueError, match="num_frequencies must be >= 0"):
        sinusoidal_encoding(torch.zeros(2, 3), -1)
