"""CLIP's byte-level BPE tokenizer (torch-free), reading ``bpe_simple_vocab_16e6.txt.gz``.

A re-implementation of OpenAI's ``SimpleTokenizer`` (``clip/simple_tokenizer.py``, MIT) with two
deliberate differences, both irrelevant to the short ASCII prompts wcbench ships:

- OpenAI runs ``ftfy.fix_text`` first; ftfy is not a dependency here, so we apply only the parts
  of it that change ordinary text (NFC normalisation, curly quotes to straight ones) and no
  mojibake repair.
- OpenAI splits words with the third-party ``regex`` module's ``\\p{L}``/``\\p{N}`` classes; we
  scan with :func:`unicodedata.category`, which gives the same pieces (a test compares both when
  ``regex`` is installed).

The vocabulary file ships in the ``open-clip-torch`` wheel; ``wcbench models pull clip-bpe-vocab``
extracts it into the model store.
"""

from __future__ import annotations

import gzip
import html
import os
import re
import unicodedata
from collections.abc import Sequence
from functools import lru_cache
from itertools import pairwise

import numpy as np

from wcbench.metrics.clip.config import EOT_TOKEN, SOT_TOKEN

#: Model-store entry holding the vocabulary file.
VOCAB_ENTRY = "clip-bpe-vocab"
_SOT, _EOT = "<|startoftext|>", "<|endoftext|>"
_CONTRACTIONS = ("'s", "'t", "'re", "'ve", "'m", "'ll", "'d")
# Lines 1 .. 48894 of the file are the merges CLIP uses (49408 tokens = 2 * 256 bytes + 48894 merges
# + 2 specials); the file holds more merges than were used.
_N_MERGES = 49152 - 256 - 2
_QUOTES = str.maketrans({"\u2018": "'", "\u2019": "'", "\u201c": '"', "\u201d": '"'})


@lru_cache(maxsize=1)
def bytes_to_unicode() -> dict[int, str]:
    """OpenAI/GPT-2's reversible map from the 256 byte values to printable unicode characters."""
    bs = [*range(ord("!"), ord("~") + 1), *range(ord("¡"), ord("¬") + 1), *range(ord("®"), ord("ÿ") + 1)]
    cs = bs[:]
    n = 0
    for b in range(256):
        if b not in bs:
            bs.append(b)
            cs.append(256 + n)
            n += 1
    return dict(zip(bs, (chr(c) for c in cs)))


def _pairs(word: tuple[str, ...]) -> set[tuple[str, str]]:
    return set(pairwise(word))


def clean_text(text: str) -> str:
    """Normalise text as CLIP's tokenizer does before splitting (see module notes), lower-cased."""
    text = unicodedata.normalize("NFC", text).translate(_QUOTES)
    text = html.unescape(html.unescape(text)).strip()
    return re.sub(r"\s+", " ", text).strip().lower()


def _is_letter(ch: str) -> bool:
    return unicodedata.category(ch).startswith("L")


def _is_number(ch: str) -> bool:
    return unicodedata.category(ch).startswith("N")


def split_words(text: str) -> list[str]:
    r"""Split cleaned text into pre-BPE pieces.

    Equivalent to ``regex.findall`` with OpenAI's pattern
    ``<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+``:
    at each position the first alternative that matches wins; whitespace is skipped.
    """
    out: list[str] = []
    i, n = 0, len(text)
    while i < n:
        ch = text[i]
        special = next((s for s in (_SOT, _EOT, *_CONTRACTIONS) if text.startswith(s, i)), None)
        if special is not None:
            out.append(special)
            i += len(special)
        elif _is_letter(ch):
            j = i + 1
            while j < n and _is_letter(text[j]):
                j += 1
            out.append(text[i:j])
            i = j
        elif _is_number(ch):
            out.append(ch)  # digits are single tokens in CLIP
            i += 1
        elif ch.isspace():
            i += 1
        else:
            j = i + 1
            while j < n and not (text[j].isspace() or _is_letter(text[j]) or _is_number(text[j])):
                j += 1
            out.append(text[i:j])
            i = j
    return out


class ClipTokenizer:
    """CLIP's tokenizer.

    Parameters
    ----------
    vocab_path : path-like
        ``bpe_simple_vocab_16e6.txt.gz`` (gzip text, one merge per line after a header line).
    context_length : int
        Length L of the rows :meth:`tokenize` returns (77 for every released CLIP).

    Raises
    ------
    ValueError
        If the file does not hold enough merges to be CLIP's vocabulary.
    """

    sot_token = SOT_TOKEN
    eot_token = EOT_TOKEN

    def __init__(self, vocab_path: str | os.PathLike[str], *, context_length: int = 77):
        with gzip.open(vocab_path, "rt", encoding="utf-8") as fh:
            lines = fh.read().split("\n")
        merges = [tuple(line.split()) for line in lines[1 : _N_MERGES + 1]]
        if len(merges) != _N_MERGES or any(len(m) != 2 for m in merges):
            raise ValueError(f"{vocab_path}: not CLIP's BPE vocabulary (expected {_N_MERGES} merge lines)")
        self.byte_encoder = bytes_to_unicode()
        self.byte_decoder = {v: k for k, v in self.byte_encoder.items()}
        vocab = list(self.byte_encoder.values())
        vocab += [v + "</w>" for v in vocab]
        vocab += ["".join(m) for m in merges]
        vocab += [_SOT, _EOT]
        self.encoder: dict[str, int] = {tok: i for i, tok in enumerate(vocab)}
        self.decoder: dict[int, str] = dict(enumerate(vocab))
        self.bpe_ranks: dict[tuple[str, ...], int] = {m: i for i, m in enumerate(merges)}
        self.context_length = context_length
        self._cache: dict[str, str] = {_SOT: _SOT, _EOT: _EOT}
        if self.encoder[_SOT] != SOT_TOKEN or self.encoder[_EOT] != EOT_TOKEN:
            raise ValueError(f"{vocab_path}: special token ids differ from CLIP's")

    @property
    def vocab_size(self) -> int:
        """Number of tokens (49408)."""
        return len(self.encoder)

    def _bpe(self, token: str) -> str:
        cached = self._cache.get(token)
        if cached is not None:
            return cached
        word: tuple[str, ...] = (*token[:-1], token[-1] + "</w>")
        pairs = _pairs(word)
        if not pairs:
            return token + "</w>"
        while True:
            bigram = min(pairs, key=lambda p: self.bpe_ranks.get(p, 1 << 62))
            if bigram not in self.bpe_ranks:
                break
            first, second = bigram
            new_word: list[str] = []
            i = 0
            while i < len(word):
                try:
                    j = word.index(first, i)
                except ValueError:
                    new_word.extend(word[i:])
                    break
                new_word.extend(word[i:j])
                i = j
                if word[i] == first and i < len(word) - 1 and word[i + 1] == second:
                    new_word.append(first + second)
                    i += 2
                else:
                    new_word.append(word[i])
                    i += 1
            word = tuple(new_word)
            if len(word) == 1:
                break
            pairs = _pairs(word)
        out = " ".join(word)
        self._cache[token] = out
        return out

    def encode(self, text: str) -> list[int]:
        """Token ids of ``text`` without start/end tokens.

        Parameters
        ----------
        text : str
            Any text; it is cleaned and lower-cased first (:func:`clean_text`).

        Returns
        -------
        list of int
            Ids in [0, 49408).
        """
        ids: list[int] = []
        for piece in split_words(clean_text(text)):
            mapped = "".join(self.byte_encoder[b] for b in piece.encode("utf-8"))
            ids.extend(self.encoder[t] for t in self._bpe(mapped).split(" "))
        return ids

    def decode(self, ids: Sequence[int]) -> str:
        """Text of token ids; start/end/padding tokens are dropped, words joined by single spaces."""
        keep = [int(i) for i in ids if int(i) not in (0, SOT_TOKEN, EOT_TOKEN)]
        text = "".join(self.decoder[i] for i in keep)
        raw = bytearray(self.byte_decoder[c] for c in text).decode("utf-8", errors="replace")
        return raw.replace("</w>", " ").strip()

    def tokenize(self, texts: str | Sequence[str], *, truncate: bool = True) -> np.ndarray:
        """Token rows for the text tower, as OpenAI's/open_clip's ``tokenize``.

        Parameters
        ----------
        texts : str or sequence of str
            T texts.
        truncate : bool
            When a text needs more than L tokens (start and end included): ``True`` cuts it to L
            tokens with the end token last (open_clip's behaviour); ``False`` raises.

        Returns
        -------
        ndarray [T, L] int64
            ``[SOT, ids..., EOT, 0, 0, ...]`` per row.

        Raises
        ------
        ValueError
            If ``truncate`` is False and a text is too long (the message names it).
        """
        if isinstance(texts, str):
            texts = [texts]
        out = np.zeros((len(texts), self.context_length), dtype=np.int64)
        for row, text in enumerate(texts):
            ids = [SOT_TOKEN, *self.encode(text), EOT_TOKEN]
            if len(ids) > self.context_length:
                if not truncate:
                    raise ValueError(
                        f"text needs {len(ids)} tokens, more than the context length {self.context_length}: "
                        f"{text[:60]!r}..."
                    )
                ids = [*ids[: self.context_length - 1], EOT_TOKEN]
            out[row, : len(ids)] = ids
        return out

    def count_tokens(self, text: str) -> int:
        """Tokens ``text`` needs, start and end tokens included."""
        return len(self.encode(text)) + 2
