"""Distributions of uncertain scenario quantities, and the seeded stream each is drawn from.

``uniform`` (``low``, ``high``), ``normal`` (``mean``, ``sd`` and required bounds ``low``,
``high``: truncated, drawn with ``scipy.stats.truncnorm``) and ``choice`` (``values``, optional
probabilities ``p``); chosen by the ``dist`` key, validated strictly (unknown keys refused).
"""

from __future__ import annotations

import zlib
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from mpcasv.config import Float, Pos, Prob, frozen

#: first spawn key of every realisation stream (keeps them apart from the world's streams,
#: :data:`mpcasv.sim.streams.CHANNEL_STREAM`)
STREAM_TAG = 0x5EED


@frozen
class Uniform:
    """Uniform on [low, high]."""

    dist: Literal["uniform"]
    low: Float
    high: Float

    @model_validator(mode="after")
    def _check(self) -> Uniform:
        if not self.high > self.low:
            raise ValueError(f"uniform needs low < high, got [{self.low}, {self.high}]")
        return self

    def support(self) -> tuple[float, float]:
        return self.low, self.high

    def draw(self, rng: np.random.Generator) -> float:
        return float(rng.uniform(self.low, self.high))


@frozen
class Normal:
    """Normal(mean, sd) truncated to [low, high] (bounds required: no unbounded draws)."""

    dist: Literal["normal"]
    mean: Float
    sd: Pos
    low: Float
    high: Float

    @model_validator(mode="after")
    def _check(self) -> Normal:
        if not (self.low < self.high and self.low <= self.mean <= self.high):
            raise ValueError(f"normal needs low <= mean <= high and low < high, got "
                             f"low={self.low}, mean={self.mean}, high={self.high}")  # fmt: skip
        return self

    def support(self) -> tuple[float, float]:
        return self.low, self.high

    def draw(self, rng: np.random.Generator) -> float:
        from scipy.stats import truncnorm

        a, b = (self.low - self.mean) / self.sd, (self.high - self.mean) / self.sd
        return float(truncnorm.rvs(a, b, loc=self.mean, scale=self.sd, random_state=rng))


@frozen
class Choice:
    """One of ``values`` (with probabilities ``p``, equal if not given)."""

    dist: Literal["choice"]
    values: tuple[Float, ...]
    p: tuple[Prob, ...] | None = None

    @model_validator(mode="after")
    def _check(self) -> Choice:
        if not self.values:
            raise ValueError("choice needs at least one value")
        if self.p is not None:
            if len(self.p) != len(self.values):
                raise ValueError(f"choice: {len(self.p)} probabilities for "
                                 f"{len(self.values)} values")  # fmt: skip
            if abs(sum(self.p) - 1.0) > 1e-9:
                raise ValueError(f"choice: probabilities sum to {sum(self.p)}, not 1")
        return self

    def support(self) -> tuple[float, float]:
        return min(self.values), max(self.values)

    def draw(self, rng: np.random.Generator) -> float:
        return float(self.values[int(rng.choice(len(self.values), p=self.p))])


Dist = Annotated[Uniform | Normal | Choice, Field(discriminator="dist")]


def stream(seed: int, key: str) -> np.random.Generator:
    """The random stream of one uncertain quantity: independent of the world's streams
    (:mod:`mpcasv.sim.streams`), of the controller and of every other key."""
    return np.random.default_rng(
        np.random.SeedSequence(seed, spawn_key=(STREAM_TAG, zlib.crc32(key.encode())))
    )


__all__ = ["Uniform", "Normal", "Choice", "Dist", "stream", "STREAM_TAG"]
