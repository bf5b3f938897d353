"""The content hash of the mesh keys and fingerprints (``rstrace_engine.accel.content_hash``):
its NH kernel is NH, bit for bit, and its digests follow the bytes and the updates."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from rstrace_engine.accel import content_hash as ch


def _nh_reference(words: np.ndarray, key: np.ndarray) -> np.ndarray:
    """NH of each block with the four shifted keys, in Python integers."""
    out = []
    for s in range(0, len(words), ch.BLOCK_WORDS):
        m = [int(x) for x in words[s:s + ch.BLOCK_WORDS]]
        row = []
        for lane in range(ch.LANES):
            k = [int(x) for x in key[lane * ch.SHIFT:lane * ch.SHIFT + len(m)]]
            acc = sum(((m[2 * i] + k[2 * i]) % 2 ** 32) * ((m[2 * i + 1] + k[2 * i + 1])
                                                           % 2 ** 32)
                      for i in range(len(m) // 2))
            row.append(acc % 2 ** 64)
        out.append(row)
    return np.array(out, np.uint64)


def test_the_kernel_is_nh_with_four_shifted_keys():
    rng = np.random.default_rng(3)
    # two full blocks and a short one; words near 2^32 (the 32-bit sums wrap)
    words = rng.integers(2 ** 32 - 50, 2 ** 32, 2 * ch.BLOCK_WORDS + 10,
                         dtype=np.uint64).astype(np.uint32)
    words[::3] = rng.integers(0, 2 ** 32, len(words[::3]), dtype=np.uint64).astype(np.uint32)
    words.flags.writeable = False
    out = np.empty((3, ch.LANES), np.uint64)
    ch._nh_blocks(words, ch._KEY, out)
    assert np.array_equal(out, _nh_reference(words, ch._KEY))


def _digest(*parts) -> bytes:
    h = ch.ContentHash()
    for p in parts:
        h.update(p)
    return h.digest()


def test_equal_bytes_give_equal_digests_and_any_changed_byte_another():
    rng = np.random.default_rng(5)
    a = rng.random((70_001, 3)).astype(np.float32)  # 840,012 bytes: blocks and a tail
    d = _digest(a)
    assert len(d) == 16
    view = a.view()
    view.flags.writeable = False
    assert _digest(view) == d == _digest(a.copy()) == _digest(a.tobytes())
    # a copy that does not start on a 4-byte boundary hashes the same bytes
    shifted = np.empty(a.nbytes + 1, np.uint8)[1:]
    shifted[:] = a.reshape(-1).view(np.uint8)
    assert shifted.ctypes.data % 4 and _digest(shifted) == d
    raw = a.reshape(-1).view(np.uint8)
    for at in (0, 5, ch.BLOCK_WORDS * 4 - 1, ch.BLOCK_WORDS * 4, len(raw) // 2,
               len(raw) - 9, len(raw) - 4, len(raw) - 1):  # (the last 4: the tail)
        b = raw.copy()
        b[at] ^= 1
        assert _digest(b) != d, at
    assert _digest(raw[:-1]) != d
    assert _digest(np.concatenate([raw, np.zeros(1, np.uint8)])) != d
    assert _digest(np.concatenate([raw, np.zeros(8, np.uint8)])) != d


def test_each_update_is_a_record_of_its_own():
    a = np.arange(1000, dtype=np.int32)
    assert _digest(a[:500], a[500:]) == _digest(a[:500], a[500:])
    assert _digest(a[:500], a[500:]) != _digest(a)
    assert _digest(b"ab", b"c") != _digest(b"a", b"bc")
    assert _digest(b"") != _digest()
    # the same bytes hashed otherwise than SHA-256 alone
    assert _digest(a) != hashlib.sha256(a).digest()[:16]


@pytest.mark.parametrize("dtype", [np.bool_, np.int32, np.float64])
def test_any_dtype_is_hashed_by_its_bytes(dtype):
    a = (np.arange(4099) % 7).astype(dtype)
    assert _digest(a) == _digest(a.reshape(-1).view(np.uint8).copy())


def test_a_large_update_hashes_its_halves_on_two_threads_to_the_same_digest(monkeypatch):
    """From ``SPLIT_BLOCKS`` blocks an update hashes the second half of its blocks beside
    (``rstrace_engine.beside``): the NH rows and the digest are the one-thread ones (main
    hashed every block on the calling thread: no ``SPLIT_BLOCKS``)."""
    import threading

    import numba

    rng = np.random.default_rng(11)
    a = rng.integers(0, 2 ** 32, ch.SPLIT_BLOCKS * ch.BLOCK_WORDS + 1001, dtype=np.uint64
                     ).astype(np.uint32)
    before = numba.get_num_threads()
    numba.set_num_threads(1)  # (Beside runs inline: every block on this thread)
    try:
        one = _digest(a)
    finally:
        numba.set_num_threads(before)
    calls = []
    kernel = ch._nh_blocks

    def recorded(words, key, out):
        calls.append((len(out), threading.get_ident()))
        kernel(words, key, out)

    monkeypatch.setattr(ch, "_nh_blocks", recorded)
    handed = []

    class Recorded(ch.Beside):
        def __init__(self, fn, *args, when=True):
            super().__init__(fn, *args, when=when)
            handed.append(self.started)

    monkeypatch.setattr(ch, "Beside", Recorded)
    if numba.get_num_threads() < 2:
        pytest.skip("one thread only here")
    assert _digest(a) == one
    blocks = ch.SPLIT_BLOCKS + 1
    assert sorted(n for n, _ in calls) == [blocks // 2, blocks - blocks // 2]
    assert handed == [True]
    calls.clear()
    _digest(a[:(ch.SPLIT_BLOCKS - 1) * ch.BLOCK_WORDS])  # (below: one call, here)
    assert calls == [(ch.SPLIT_BLOCKS - 1, threading.get_ident())] and handed == [True]
