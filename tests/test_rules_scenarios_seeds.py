"""The derivation of the worlds' and the trackers' random streams, spelled out independently
of the code: every stored number (the `bayes` references, the reproductions' references,
the tuned studies) depends on it, so a change to any detail (the hash, its byte order, a
tag) must fail here in milliseconds, not only in the minutes-long `--check --exact` runs."""

from __future__ import annotations

import hashlib
import zlib

import numpy as np
import pytest

from mttbench.scenarios.simulator import TRACKER_TAG, stable_hash, tracker_seed, world_seed


def test_stable_hash_is_crc32_of_the_utf8_name():
    # the CRC-32 of "default" from its definition: reflected polynomial 0xEDB88320
    def crc32(data: bytes) -> int:
        crc = 0xFFFFFFFF
        for byte in data:
            crc ^= byte
            for _ in range(8):
                crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)
        return crc ^ 0xFFFFFFFF

    for name in ("default", "env-pf-0.1", "ünïcode"):
        assert stable_hash(name) == crc32(name.encode("utf-8")) == zlib.crc32(name.encode())


@pytest.mark.parametrize("identity", ["gpf", "jmpd-ap:n_particles=64000,init_fraction=1.0"])
def test_tracker_seed_reads_the_sha256_prefix_little_endian(identity):
    digest = hashlib.sha256(identity.encode("utf-8")).digest()
    # little-endian: the 16th byte is the most significant (spelled out, not from_bytes)
    key = int("".join(f"{b:02x}" for b in reversed(digest[:16])), 16)
    ss = tracker_seed("default", 7, identity)
    assert ss.entropy == 7
    assert ss.spawn_key == (stable_hash("default"), TRACKER_TAG, key)
    big = int(digest[:16].hex(), 16)
    assert key != big  # the two byte orders differ for these identities
    expected = np.random.SeedSequence(7, spawn_key=(stable_hash("default"), 3, key))
    assert np.array_equal(ss.generate_state(4), expected.generate_state(4))


def test_world_and_tracker_streams_are_distinct_spawn_keys():
    assert world_seed("default", 3, 0).spawn_key == (stable_hash("default"), 0)
    assert world_seed("default", 3, 1, 5).spawn_key == (stable_hash("default"), 1, 5)
    assert TRACKER_TAG == 3  # not 0 (truth), 1 (looks) or 2 (the linear sensor)
    a = np.random.default_rng(tracker_seed("default", 3, "gpf")).random(3)
    b = np.random.default_rng(tracker_seed("default", 3, "kfnn")).random(3)
    c = np.random.default_rng(tracker_seed("births", 3, "gpf")).random(3)
    assert not np.array_equal(a, b) and not np.array_equal(a, c)
