"""Reverb-style SampleToInsertRatio rate limiter, counted in transitions.

``diff = inserts * spi - samples`` must stay inside ``[min_diff, max_diff]`` with
``min_diff = spi * min_size - buffer`` and ``max_diff = spi * min_size + buffer``: a sample
that would push ``diff`` below ``min_diff`` waits for inserts, an insert that would push it
above ``max_diff`` waits for samples (only when ``limit_inserts``). So after the first
``min_size`` inserts the learner gets ``spi`` sampled transitions per inserted one, give or
take ``buffer``. ``spi == 0`` keeps only the minimum size. The limiter never waits itself:
callers poll it with a deadline, and every refusal carries a reason.
"""
from __future__ import annotations


class RateLimiter:
    def __init__(self, samples_per_insert: float, min_size: int, error_buffer: float, limit_inserts: bool = False):
        if samples_per_insert < 0:
            raise ValueError("samples_per_insert must be >= 0")
        if samples_per_insert > 0 and error_buffer < max(1.0, samples_per_insert):
            raise ValueError(
                f"samples_per_insert_error_buffer={error_buffer} is narrower than "
                f"max(1, spi)={max(1.0, samples_per_insert)}: "
                "that deadlocks (Reverb rejects such windows too); it should also be >= the batch size"
            )
        self.spi = float(samples_per_insert)
        self.min_size = int(min_size)
        self.buffer = float(error_buffer)
        self.limit_inserts = bool(limit_inserts)
        self.inserts = 0  #: transitions inserted (ever, restored from checkpoints)
        self.samples = 0  #: transitions sampled (ever)

    @property
    def min_diff(self) -> float:
        return self.spi * self.min_size - self.buffer

    @property
    def max_diff(self) -> float:
        return self.spi * self.min_size + self.buffer

    @property
    def diff(self) -> float:
        return self.inserts * self.spi - self.samples

    def achieved(self) -> float:
        """Samples per insert achieved so far (transitions)."""
        return self.samples / self.inserts if self.inserts else 0.0

    def sample_block_reason(self, n: int, size: int) -> str:
        """Empty string if ``n`` transitions may be sampled now, else why not."""
        if size < max(1, self.min_size):
            return f"replay holds {size} transitions, sampling starts at min_size_to_sample={self.min_size}"
        if self.spi > 0 and self.diff - n < self.min_diff:
            return (
                f"samples-per-insert limit: {self.samples} sampled for {self.inserts} inserted "
                f"(target {self.spi:g} per insert after {self.min_size}, buffer {self.buffer:g}); waiting for inserts"
            )
        return ""

    def insert_block_reason(self, n: int) -> str:
        """Empty string if ``n`` transitions may be inserted now, else why not."""
        if self.limit_inserts and self.spi > 0 and self.diff + n * self.spi > self.max_diff:
            return (
                f"samples-per-insert limit: {self.inserts} inserted but only {self.samples} sampled "
                f"(target {self.spi:g}, buffer {self.buffer:g}); waiting for the learner"
            )
        return ""
