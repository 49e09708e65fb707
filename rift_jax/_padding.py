"""Sizes that share compiled programs.

XLA compiles one program per array shape. A support, a screen's candidates and RIFT's
active set each hold a different number of points in every run, and at the stress grid's
scale compiling is most of a run: a FISTA fit on a 30-view, 1,475-point support took 28 s
the first time and 1.7 s once its programs were compiled, LSMR 8.9 s and 2.2 s, RIFT(N)
25 s and 9.6 s (2-core CPU). Padding a count up to the next size of a ladder lets runs whose
counts differ a little share one program, for at most ``1/per_octave`` more arithmetic.
The padded points are copies of a real one that hold ρ = 0 (`GRT.live`; `grt_operator`'s
``pad_to``), so they change no result.
"""

from __future__ import annotations


def ladder_size(n: int, per_octave: int = 4) -> int:
    """The smallest size ≥ ``n`` of the form m·2^e with m in ``per_octave`` ..
    ``2·per_octave − 1`` (``per_octave`` sizes per octave, each at most ``1/per_octave``
    above the count it holds); counts up to ``per_octave`` are their own size."""
    if per_octave < 1 or per_octave & (per_octave - 1):
        raise ValueError(f"ladder_size: `per_octave` must be a power of two, got {per_octave}.")
    if n <= per_octave:
        return max(n, 1)
    e = (n - 1).bit_length() - per_octave.bit_length()  # per_octave·2^e < n ≤ 2^(e+1)·…
    return -(-n // 2**e) * 2**e
