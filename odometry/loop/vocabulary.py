"""A DBoW-like vocabulary tree over 256-bit ORB descriptors: hierarchical k-majority clustering
(branching k, depth L, so up to k^L words), idf weights, and L1-normalised tf-idf bag-of-words vectors.
Everything is vectorised: Hamming distances come from one matrix product on unpacked bits."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from leovr.data.io import atomic_write
from leovr.errors import DataError


def unpack(desc: np.ndarray) -> np.ndarray:
    """N x 32 uint8 -> N x 256 float32 of 0/1."""
    return np.unpackbits(np.asarray(desc, np.uint8), axis=1).astype(np.float32)


def hamming(bits: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """N x 256 and k x 256 (0/1) -> N x k Hamming distances."""
    return bits.sum(1, keepdims=True) + centers.sum(1)[None] - 2.0 * bits @ centers.T


def k_majority(bits: np.ndarray, k: int, rng: np.random.Generator, iters: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Cluster binary vectors: k-means++-style seeding, assignment by Hamming distance, centre = bitwise majority."""
    n = len(bits)
    centers = [bits[rng.integers(n)]]
    d = hamming(bits, centers[0][None])[:, 0]
    for _ in range(1, k):
        p = d**2 / max(float((d**2).sum()), 1e-9)
        centers.append(bits[rng.choice(n, p=p) if p.sum() > 0 else rng.integers(n)])
        d = np.minimum(d, hamming(bits, centers[-1][None])[:, 0])
    C = np.stack(centers)
    for _ in range(iters):
        label = hamming(bits, C).argmin(1)
        counts = np.bincount(label, minlength=k)
        sums = np.zeros_like(C)
        np.add.at(sums, label, bits)
        newC = np.where(counts[:, None] > 0, (sums >= counts[:, None] / 2.0).astype(np.float32), C)
        if np.array_equal(newC, C):
            break
        C = newC
    return C, hamming(bits, C).argmin(1)


@dataclass
class Vocabulary:
    """Full k-ary tree stored level by level: `centers[l]` is (k^(l+1)) x 256; word = leaf index."""

    k: int
    levels: int
    centers: list[np.ndarray]
    idf: np.ndarray  # per word

    @property
    def words(self) -> int:
        return self.k**self.levels

    @classmethod
    def train(
        cls, desc: np.ndarray, k: int = 10, levels: int = 5, seed: int = 0, docs: list[np.ndarray] | None = None
    ) -> "Vocabulary":
        """Cluster the descriptors level by level; `docs` (descriptor sets, one per image) give the idf."""
        rng = np.random.default_rng(seed)
        bits = unpack(desc)
        node = np.zeros(len(bits), np.int64)  # node index within the current level
        centers = []
        for _ in range(levels):
            n_nodes = k ** len(centers)
            level_c = np.zeros((n_nodes * k, 256), np.float32)
            child = np.zeros(len(bits), np.int64)
            parent_c = centers[-1] if centers else np.zeros((1, 256), np.float32)
            for j in range(n_nodes):
                idx = np.nonzero(node == j)[0]
                if len(idx) >= k:
                    C, lab = k_majority(bits[idx], k, rng)
                else:  # too few descriptors: children copy the parent (its words stay empty)
                    C = np.repeat(parent_c[j][None], k, 0)
                    lab = np.zeros(len(idx), np.int64)
                level_c[j * k : (j + 1) * k] = C
                child[idx] = j * k + lab
            centers.append(level_c)
            node = child
        voc = cls(k, levels, centers, np.ones(k**levels, np.float32))
        if docs:
            df = np.zeros(voc.words)
            for d in docs:
                if len(d):
                    df[np.unique(voc.words_of(d))] += 1
            voc.idf = np.log(len(docs) / np.maximum(df, 1.0)).astype(np.float32)
        return voc

    def words_of(self, desc: np.ndarray) -> np.ndarray:
        """Leaf word of each descriptor (descending the tree, all descriptors at once)."""
        bits = unpack(desc)
        node = np.zeros(len(bits), np.int64)
        for level in range(self.levels):
            kids = node[:, None] * self.k + np.arange(self.k)[None]  # N x k child indices
            C = self.centers[level][kids]  # N x k x 256
            d = bits.sum(1)[:, None] + C.sum(2) - 2.0 * np.einsum("nb,nkb->nk", bits, C)
            node = kids[np.arange(len(bits)), d.argmin(1)]
        return node

    def bow(self, desc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sparse L1-normalised tf-idf vector: (word ids, weights)."""
        if len(desc) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.float32)
        words, counts = np.unique(self.words_of(desc), return_counts=True)
        w = counts / counts.sum() * self.idf[words]
        s = w.sum()
        return words, (w / s if s > 0 else w).astype(np.float32)

    def save(self, path: str | Path) -> None:
        packed = [np.packbits(c.astype(np.uint8), axis=1) for c in self.centers]
        atomic_write(
            Path(path),
            lambda tmp: np.savez_compressed(
                open(tmp, "wb"),
                k=self.k,
                levels=self.levels,
                idf=self.idf,
                **{f"c{i}": p for i, p in enumerate(packed)},
            ),
        )

    @classmethod
    def load(cls, path: str | Path) -> "Vocabulary":
        path = Path(path)
        if not path.is_file():
            raise DataError(path, "vocabulary file not found")
        try:
            z = np.load(path)
            k, levels = int(z["k"]), int(z["levels"])
            centers = [np.unpackbits(z[f"c{i}"], axis=1).astype(np.float32) for i in range(levels)]
            idf = z["idf"]
        except Exception as exc:  # numpy raises several types for corrupt archives
            raise DataError(path, f"not a leovr vocabulary: {exc}") from exc
        if any(len(c) != k ** (i + 1) for i, c in enumerate(centers)) or len(idf) != k**levels:
            raise DataError(path, "vocabulary arrays do not match its k and levels")
        return cls(k, levels, centers, idf)


def score(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> float:
    """DBoW2's L1 score of two normalised vectors: sum over shared words of min(a, b), in [0, 1]."""
    common, ia, ib = np.intersect1d(a[0], b[0], assume_unique=True, return_indices=True)
    return float(np.minimum(a[1][ia], b[1][ib]).sum()) if len(common) else 0.0
