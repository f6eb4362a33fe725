"""openpi's client-side image preparation for LIBERO: scale to fit, keep the aspect ratio, pad with black.

openpi's LIBERO client sends its server 224x224 images made from LIBERO's 256 px renders with
`openpi_client.image_tools.resize_with_pad` (PIL bilinear, padding centred). `resize_with_pad` here does
the same arithmetic, so `obs="vla"` with `vla_image_size=224` gives a server the pixels openpi's own loop
would (tested against openpi-client where it is installed), without requiring the package.
"""

from __future__ import annotations

import numpy as np
from PIL import Image


def resize_with_pad(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """`image` (H, W, C uint8) scaled by one factor to fit `height` x `width` (bilinear), centred on black."""
    rows, cols = image.shape[:2]
    ratio = max(cols / width, rows / height)
    new_rows, new_cols = int(rows / ratio), int(cols / ratio)
    resized = np.asarray(Image.fromarray(image).resize((new_cols, new_rows), resample=Image.BILINEAR))
    out = np.zeros((height, width, image.shape[2]), dtype=image.dtype)
    top, left = max(0, (height - new_rows) // 2), max(0, (width - new_cols) // 2)
    out[top : top + new_rows, left : left + new_cols] = resized
    return out
