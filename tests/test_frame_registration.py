"""frame_registration: a frame shifted against the avatar's picture is registered back."""
import torch

from pipeline.fit import frame_registration as registration


def _pattern(rows, columns):
    """A picture with edges both ways and a soft texture: (..., 3)."""
    return torch.stack([torch.sigmoid((columns - 40 + 0.03 * rows) / 1.0) * 0.6 + 0.2,
                        torch.sigmoid((rows - 50) / 1.5) * 0.3 + 0.3,
                        0.5 + 0.2 * torch.sin(columns / 5) * torch.cos(rows / 7)], -1)


def test_a_frame_shifted_by_a_known_amount_is_registered_back_and_explains_the_picture():
    size = 96
    rows, columns = torch.meshgrid(torch.arange(size, dtype=torch.float64), torch.arange(size, dtype=torch.float64),
                                   indexing="ij")
    frame = _pattern(rows, columns)
    inside = torch.zeros(size, size, dtype=torch.bool)
    inside[10:86, 10:86] = True
    pixels = inside.nonzero().to(torch.float64)
    shift = torch.tensor([0.8, -1.3], dtype=torch.float64)
    predicted = _pattern(pixels[:, 0] + shift[0], pixels[:, 1] + shift[1])   # the frame's picture lies `shift` on
    origin, field = registration.frame_field(frame, pixels, predicted, 16.0, 2.0, steps=5)
    places = registration.shifted_places(pixels, origin, 16.0, field)
    found = (places - pixels).mean(0)
    assert torch.allclose(found, shift, atol=0.15), found
    before = (registration._bilinear(frame, pixels) - predicted).abs().mean()
    after = (registration._bilinear(frame, places) - predicted).abs().mean()
    assert after < 0.1 * before
    assert registration.still_inside(inside, places).float().mean() > 0.9


def test_a_frame_that_agrees_with_the_picture_is_left_where_it_is():
    size = 64
    rows, columns = torch.meshgrid(torch.arange(size, dtype=torch.float64), torch.arange(size, dtype=torch.float64),
                                   indexing="ij")
    frame = _pattern(rows, columns)
    pixels = torch.stack([rows, columns], -1)[8:56, 8:56].reshape(-1, 2)
    _, field = registration.frame_field(frame, pixels, _pattern(pixels[:, 0], pixels[:, 1]), 16.0, 2.0)
    assert field.abs().max() < 1e-6
