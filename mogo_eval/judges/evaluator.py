"""Text-motion evaluators: the shared embedding space in which Guo et al. 2022's metrics are measured.

Two evaluators, one interface (`embed_motions`, `embed_texts`):

- `T2MEvaluator`: the original evaluator of Guo et al. (CVPR 2022, "Generating Diverse and Natural 3D Human
  Motions from Text"), whose pretrained `text_mot_match` weights every HumanML3D / KIT-ML paper (MOGO's Table 2
  included) reports with. The three modules below reproduce its architecture with the checkpoint's key names, so
  a user who has the files loads them as they are:

      ev = T2MEvaluator.from_files("checkpoints/t2m/text_mot_match/model/finest.tar", glove_dir="glove",
                                   meta_dir="checkpoints/t2m/Comp_v6_KLD01/meta")

  (`finest.tar` from the text-to-motion repository's checkpoints, `glove/our_vab_{data.npy,words.pkl,idx.pkl}`
  its GloVe subset, `meta/{mean,std}.npy` the statistics its motions were normalised with.) Those weights cannot be
  downloaded here, so this path is checked with weights of the same shapes, not with the real file.

- `ContrastiveEvaluator`: the default, trained on any dataset folder by `mogo_eval.protocol.train_evaluator`.
  Motion side: Guo's strided-conv "movement" units (4 frames each), then dilated convolutions and pooling
  (a GRU trained too slowly on 2 CPU cores) -> 512; text side: the frozen MiniLM sentence embedding -> MLP ->
  512; trained with a symmetric InfoNCE loss. Its numbers are comparable
  with each other (rows of one table), never with published HumanML3D numbers.
"""
from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from torch.nn.utils.rnn import pack_padded_sequence

# ---------------------------------------------------------------------------------------------------------
# Guo et al.'s modules (text-to-motion networks/modules.py). Attribute names are the checkpoint's keys:
# movement_encoder: main.0, main.3, out_net; motion/text_encoder: input_emb, gru, output_net.{0,1,3}, hidden
# (text_encoder also pos_emb). Dropout sits between conv and activation, as there; it is off in eval mode.


def init_weight(m: nn.Module) -> None:
    if isinstance(m, (nn.Conv1d, nn.Linear, nn.ConvTranspose1d)):
        nn.init.xavier_normal_(m.weight)
        if m.bias is not None:
            nn.init.constant_(m.bias, 0)


class MovementConvEncoder(nn.Module):
    """(B, T, D) frames -> (B, T // 4, output_size) movement units: two stride-2 convolutions."""

    def __init__(self, input_size: int, hidden_size: int, output_size: int):
        super().__init__()
        self.main = nn.Sequential(
            nn.Conv1d(input_size, hidden_size, 4, 2, 1),
            nn.Dropout(0.2),
            nn.LeakyReLU(0.2),
            nn.Conv1d(hidden_size, output_size, 4, 2, 1),
            nn.Dropout(0.2),
            nn.LeakyReLU(0.2),
        )
        self.out_net = nn.Linear(output_size, output_size)
        self.main.apply(init_weight)
        self.out_net.apply(init_weight)

    def forward(self, x):                                          # x (B, T, D)
        return self.out_net(self.main(x.transpose(1, 2)).transpose(1, 2))   # (B, T // 4, output_size)


def _co_head(hidden_size: int, output_size: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(hidden_size * 2, hidden_size), nn.LayerNorm(hidden_size), nn.LeakyReLU(0.2),
                         nn.Linear(hidden_size, output_size))


class MotionEncoderBiGRUCo(nn.Module):
    """Movement units (B, T', input_size) + lengths (B,) -> (B, output_size): last states of a BiGRU."""

    def __init__(self, input_size: int, hidden_size: int, output_size: int):
        super().__init__()
        self.input_emb = nn.Linear(input_size, hidden_size)
        self.gru = nn.GRU(hidden_size, hidden_size, batch_first=True, bidirectional=True)
        self.output_net = _co_head(hidden_size, output_size)
        self.input_emb.apply(init_weight)
        self.output_net.apply(init_weight)
        self.hidden_size = hidden_size
        self.hidden = nn.Parameter(torch.randn((2, 1, hidden_size)))          # learned initial state

    def forward(self, x, lengths):                                 # x (B, T', C), lengths (B,) in units
        h0 = self.hidden.repeat(1, x.shape[0], 1)                   # (2, B, H)
        packed = pack_padded_sequence(self.input_emb(x), lengths.cpu(), batch_first=True, enforce_sorted=False)
        _, last = self.gru(packed, h0)                              # (2, B, H)
        return self.output_net(torch.cat([last[0], last[1]], dim=-1))


class TextEncoderBiGRUCo(nn.Module):
    """GloVe word vectors (B, S, 300) + POS one-hots (B, S, 15) + lengths (B,) -> (B, output_size)."""

    def __init__(self, word_size: int, pos_size: int, hidden_size: int, output_size: int):
        super().__init__()
        self.pos_emb = nn.Linear(pos_size, word_size)
        self.input_emb = nn.Linear(word_size, hidden_size)
        self.gru = nn.GRU(hidden_size, hidden_size, batch_first=True, bidirectional=True)
        self.output_net = _co_head(hidden_size, output_size)
        self.input_emb.apply(init_weight)
        self.pos_emb.apply(init_weight)
        self.output_net.apply(init_weight)
        self.hidden_size = hidden_size
        self.hidden = nn.Parameter(torch.randn((2, 1, hidden_size)))

    def forward(self, word_embs, pos_onehot, cap_lens):
        x = self.input_emb(word_embs + self.pos_emb(pos_onehot))    # (B, S, H)
        h0 = self.hidden.repeat(1, x.shape[0], 1)
        packed = pack_padded_sequence(x, cap_lens.cpu(), batch_first=True, enforce_sorted=False)
        _, last = self.gru(packed, h0)
        return self.output_net(torch.cat([last[0], last[1]], dim=-1))


# ---------------------------------------------------------------------------------------------------------
# Guo et al.'s word features: GloVe vectors plus a one-hot part of speech, with motion words promoted to their
# own "VIP" classes (utils/word_vectorizer.py).

POS_ENUMERATOR = {"VERB": 0, "NOUN": 1, "DET": 2, "ADP": 3, "NUM": 4, "AUX": 5, "PRON": 6, "ADJ": 7, "ADV": 8,
                  "Loc_VIP": 9, "Body_VIP": 10, "Obj_VIP": 11, "Act_VIP": 12, "Desc_VIP": 13, "OTHER": 14}
VIP_WORDS = {
    "Loc_VIP": ("left", "right", "clockwise", "counterclockwise", "anticlockwise", "forward", "back", "backward",
                "up", "down", "straight", "curve"),
    "Body_VIP": ("arm", "chin", "foot", "feet", "face", "hand", "mouth", "leg", "waist", "eye", "knee", "shoulder",
                 "thigh"),
    "Obj_VIP": ("stair", "dumbbell", "chair", "window", "floor", "car", "ball", "handrail", "baseball", "basketball"),
    "Act_VIP": ("walk", "run", "swing", "pick", "bring", "kick", "put", "squat", "throw", "hop", "dance", "jump",
                "turn", "stumble", "dance", "stop", "sit", "lift", "lower", "raise", "wash", "stand", "kneel",
                "stroll", "rub", "bend", "balance", "flap", "jog", "shuffle", "lean", "rotate", "spin", "spread",
                "climb"),
    "Desc_VIP": ("slowly", "carefully", "fast", "careful", "slow", "quickly", "happy", "angry", "sad", "happily",
                 "angrily", "sadly"),
}


class WordVectorizer:
    """`word/POS` -> (GloVe vector, POS one-hot), from Guo et al.'s `glove/` folder (`our_vab_*` files)."""

    def __init__(self, glove_dir: str | Path, prefix: str = "our_vab"):
        glove_dir = Path(glove_dir)
        files = [glove_dir / f"{prefix}_{n}" for n in ("data.npy", "words.pkl", "idx.pkl")]
        for f in files:
            if not f.is_file():
                raise FileNotFoundError(f"GloVe file missing: {f} (Guo et al.'s glove/ folder holds "
                                        f"{prefix}_data.npy, {prefix}_words.pkl, {prefix}_idx.pkl)")
        vectors = np.load(files[0])
        # Pickles from the original release: only point this at files you trust.
        words = pickle.loads(files[1].read_bytes())
        word2idx = pickle.loads(files[2].read_bytes())
        self.word2vec = {w: vectors[word2idx[w]].astype(np.float32) for w in words}
        if "unk" not in self.word2vec:
            raise ValueError(f"{files[1]}: the vocabulary has no 'unk' entry")
        self.dim = int(vectors.shape[1])

    @staticmethod
    def pos_onehot(pos: str) -> np.ndarray:
        v = np.zeros(len(POS_ENUMERATOR), np.float32)
        v[POS_ENUMERATOR.get(pos, POS_ENUMERATOR["OTHER"])] = 1
        return v

    def __getitem__(self, item: str) -> tuple[np.ndarray, np.ndarray]:
        word, pos = item.rsplit("/", 1)
        if word not in self.word2vec:
            return self.word2vec["unk"], self.pos_onehot("OTHER")
        vip = next((k for k, words in VIP_WORDS.items() if word in words), None)
        return self.word2vec[word], self.pos_onehot(vip or pos)


def guo_token_sequence(tokens: list[str], max_text_len: int = 20) -> tuple[list[str], int]:
    """sos + at most `max_text_len` tokens + eos, padded with unk to max_text_len + 2; -> (tokens, length)."""
    tokens = ["sos/OTHER"] + list(tokens)[:max_text_len] + ["eos/OTHER"]
    length = len(tokens)
    return tokens + ["unk/OTHER"] * (max_text_len + 2 - length), length


# ---------------------------------------------------------------------------------------------------------
# The interface the protocol uses, and its two implementations.

def pad_motions(clips: list[np.ndarray], unit_length: int, max_frames: int,
                pad_to_max: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised clips (T_i, D) -> zero-padded (B, T, D) and lengths in frames (B,).

    Each clip is cut to at most `max_frames` and down to a multiple of `unit_length` (as T2M's evaluation
    dataset does); a clip shorter than one unit is first extended by repeating its last frame, so a one-token
    generation still gets an embedding. `pad_to_max` pads every clip to `max_frames`, as T2M's loaders do
    (its movement encoder sees the padding at a clip's end, so this keeps its embeddings what they were there).
    """
    out = []
    for c in clips:
        if len(c) == 0:
            raise ValueError("cannot embed an empty motion (0 frames)")
        c = c[:max_frames]
        if len(c) < unit_length:
            c = np.concatenate([c, np.repeat(c[-1:], unit_length - len(c), axis=0)])
        out.append(c[:len(c) // unit_length * unit_length])
    T = max_frames if pad_to_max else max(len(c) for c in out)
    x = np.zeros((len(out), T, out[0].shape[1]), np.float32)
    for i, c in enumerate(out):
        x[i, :len(c)] = c
    return torch.from_numpy(x), torch.tensor([len(c) for c in out])


class Evaluator:
    """What the protocol needs: motions (de-normalised features) and captions -> points of one embedding space."""
    name: str
    dim: int
    unit_length: int
    max_frames: int
    mean: np.ndarray              # (D,) statistics the evaluator normalises motions with
    std: np.ndarray
    pad_to_max = False            # pad every batch to max_frames (see pad_motions)

    def embed_motions(self, features: list[np.ndarray], batch_size: int = 64) -> np.ndarray:
        """De-normalised (T_i, D) clips -> (N, dim)."""
        out = []
        for i in range(0, len(features), batch_size):
            clips = [((f - self.mean) / self.std).astype(np.float32) for f in features[i:i + batch_size]]
            x, lengths = pad_motions(clips, self.unit_length, self.max_frames, self.pad_to_max)
            out.append(self._embed_motion_batch(x, lengths))
        return np.concatenate(out) if out else np.zeros((0, self.dim), np.float32)

    def embed_texts(self, texts: list[str], tokens: list[list[str]] | None = None) -> np.ndarray:
        """Captions (and their `word/POS` tokens, which only T2MEvaluator reads) -> (N, dim)."""
        raise NotImplementedError

    def _embed_motion_batch(self, x: torch.Tensor, lengths: torch.Tensor) -> np.ndarray:
        raise NotImplementedError


class T2MEvaluator(Evaluator):
    """Guo et al.'s evaluator with its sizes (HumanML3D: 263-dim poses, foot contacts dropped; KIT: 251)."""
    name = "t2m-text_mot_match"
    unit_length = 4
    max_frames = 196              # T2M's max_motion_length
    max_text_len = 20
    pad_to_max = True

    def __init__(self, movement_encoder: MovementConvEncoder, motion_encoder: MotionEncoderBiGRUCo,
                 text_encoder: TextEncoderBiGRUCo, words: WordVectorizer, mean: np.ndarray, std: np.ndarray):
        self.movement_encoder = movement_encoder.eval()
        self.motion_encoder = motion_encoder.eval()
        self.text_encoder = text_encoder.eval()
        self.words, self.mean, self.std = words, np.asarray(mean, np.float32), np.asarray(std, np.float32)
        self.dim = motion_encoder.output_net[-1].out_features

    @staticmethod
    def build(dim_pose: int = 263, dim_word: int = 300, dim_pos: int = len(POS_ENUMERATOR), movement_hidden: int = 512,
              movement_latent: int = 512, motion_hidden: int = 1024, text_hidden: int = 512, coemb: int = 512):
        """The three modules at Guo et al.'s sizes (EvaluatorModelWrapper's options)."""
        return (MovementConvEncoder(dim_pose - 4, movement_hidden, movement_latent),
                MotionEncoderBiGRUCo(movement_latent, motion_hidden, coemb),
                TextEncoderBiGRUCo(dim_word, dim_pos, text_hidden, coemb))

    @classmethod
    def from_files(cls, checkpoint: str | Path, glove_dir: str | Path, meta_dir: str | Path) -> "T2MEvaluator":
        """`finest.tar` (or the `t2m`/`kit` checkpoint folder holding text_mot_match/model/finest.tar), the GloVe
        folder and the folder with the evaluator's normalisation statistics (mean.npy, std.npy)."""
        checkpoint, meta_dir = Path(checkpoint), Path(meta_dir)
        if checkpoint.is_dir():
            checkpoint = checkpoint / "text_mot_match" / "model" / "finest.tar"
        if not checkpoint.is_file():
            raise FileNotFoundError(f"T2M evaluator checkpoint not found: {checkpoint}")
        mean_std = [meta_dir / "mean.npy", meta_dir / "std.npy"]
        for f in mean_std:
            if not f.is_file():
                raise FileNotFoundError(f"T2M evaluator statistics missing: {f}")
        mean, std = (np.load(f).astype(np.float32) for f in mean_std)
        # The original file is a pickle that also holds optimizer state and epoch numbers, so it needs
        # weights_only=False: only load a file you trust.
        payload = torch.load(checkpoint, map_location="cpu", weights_only=False)
        missing = [k for k in ("movement_encoder", "motion_encoder", "text_encoder") if k not in payload]
        if missing:
            raise ValueError(f"{checkpoint}: no {missing} entries; is it text_mot_match's finest.tar?")
        words = WordVectorizer(glove_dir)
        modules = cls.build(dim_pose=int(mean.shape[0]), dim_word=words.dim)
        for module, key in zip(modules, ("movement_encoder", "motion_encoder", "text_encoder")):
            module.load_state_dict(payload[key])
        return cls(*modules, words, mean, std)

    @torch.no_grad()
    def _embed_motion_batch(self, x, lengths):
        movements = self.movement_encoder(x[..., :-4])                  # foot contacts are not used
        return self.motion_encoder(movements, lengths // self.unit_length).numpy()

    @torch.no_grad()
    def embed_texts(self, texts, tokens=None):
        if tokens is None or len(tokens) != len(texts):
            raise ValueError("the T2M evaluator reads each caption's word/POS tokens (texts/<id>.txt's 2nd field)")
        words, poses, lengths = [], [], []
        for toks in tokens:
            seq, n = guo_token_sequence(toks, self.max_text_len)
            pairs = [self.words[t] for t in seq]
            words.append(np.stack([w for w, _ in pairs]))
            poses.append(np.stack([p for _, p in pairs]))
            lengths.append(n)
        return self.text_encoder(torch.from_numpy(np.stack(words)), torch.from_numpy(np.stack(poses)),
                                 torch.tensor(lengths)).numpy()


@dataclass
class EvaluatorConfig:
    input_dim: int = 263            # motion features per frame (normalised with the checkpoint's mean/std)
    motion_width: int = 128         # channels of the motion encoder
    motion_dilations: tuple = (1, 2, 4)   # residual convolutions over movement units
    text_dim: int = 384             # sentence embedding size of `text_encoder`
    hidden: int = 512               # width of the MLP heads of both towers
    embed_dim: int = 512            # the shared text-motion space (Guo et al.: 512)
    unit_length: int = 4            # frames per movement unit: the two stride-2 convolutions
    max_frames: int = 196           # longer motions are cut (T2M's max_motion_length)
    dropout: float = 0.1
    text_encoder: str = "all-MiniLM-L6-v2"   # frozen; its sentence embedding is the text input
    temperature: float = 0.07       # InfoNCE temperature on cosine similarities


def _mask(lengths, T: int):                                         # -> (B, 1, T) bool
    return (torch.arange(T, device=lengths.device)[None] < lengths[:, None])[:, None]


class MotionConvEncoder(nn.Module):
    """(B, T, D) normalised frames + lengths -> (B, embed_dim).

    A per-frame projection, then two stride-2 convolutions make one movement unit per 4 frames (as Guo et al.'s
    movement encoder), dilated residual convolutions mix units, then masked mean + max pooling and an MLP.
    Convolutions instead of Guo et al.'s BiGRU: the GRU trained ~20x slower on 2 CPU cores. Padded positions are
    zeroed after each layer, so a clip's embedding does not depend on the other clips of its batch.
    """

    def __init__(self, cfg: "EvaluatorConfig"):
        super().__init__()
        w = cfg.motion_width
        self.proj = nn.Linear(cfg.input_dim, w)
        self.down = nn.ModuleList([nn.Conv1d(w, w, 4, 2, 1), nn.Conv1d(w, w, 4, 2, 1)])
        self.blocks = nn.ModuleList([nn.Conv1d(w, w, 3, padding=d, dilation=d) for d in cfg.motion_dilations])
        self.head = nn.Sequential(nn.Dropout(cfg.dropout), nn.Linear(2 * w, cfg.hidden), nn.LayerNorm(cfg.hidden),
                                  nn.LeakyReLU(0.2), nn.Linear(cfg.hidden, cfg.embed_dim))
        self.apply(init_weight)

    def forward(self, x, lengths):                                  # x (B, T, D), T a multiple of 4
        h = F.leaky_relu(self.proj(x), 0.2).transpose(1, 2) * _mask(lengths, x.shape[1])   # (B, w, T)
        n = lengths
        for conv in self.down:
            n = n // 2
            h = F.leaky_relu(conv(h), 0.2)                          # (B, w, T / 2), then T / 4
            h = h * _mask(n, h.shape[-1])
        m = _mask(n, h.shape[-1])                                   # (B, 1, T / 4)
        for conv in self.blocks:
            h = (h + F.leaky_relu(conv(h), 0.2)) * m
        mean = h.sum(-1) / n[:, None].clamp(min=1)                  # (B, w)
        mx = h.masked_fill(~m, float("-inf")).amax(-1)              # (B, w)
        return self.head(torch.cat([mean, mx], dim=-1))             # (B, embed_dim)


class ContrastiveEvaluator(nn.Module):
    """Motion: MotionConvEncoder -> 512; text: frozen sentence embedding -> MLP -> 512; both L2-normalised, so
    the protocol's Euclidean distances rank as the training objective's cosine similarities do."""

    def __init__(self, cfg: EvaluatorConfig):
        super().__init__()
        self.cfg = cfg
        self.motion_encoder = MotionConvEncoder(cfg)
        self.text_head = nn.Sequential(nn.Linear(cfg.text_dim, cfg.hidden), nn.LayerNorm(cfg.hidden),
                                       nn.LeakyReLU(0.2), nn.Dropout(cfg.dropout), nn.Linear(cfg.hidden, cfg.embed_dim))
        self.text_head.apply(init_weight)

    def encode_motion(self, x, lengths):
        """x (B, T, D) normalised, T a multiple of unit_length; lengths (B,) frames -> (B, embed_dim) unit norm."""
        return F.normalize(self.motion_encoder(x, lengths), dim=-1)

    def encode_text(self, sentence_emb):
        """(B, text_dim) frozen sentence embeddings -> (B, embed_dim) unit norm."""
        return F.normalize(self.text_head(sentence_emb), dim=-1)

    def loss(self, x, lengths, sentence_emb, caption_ids):
        """Symmetric InfoNCE over the batch. Other rows with the same caption are not counted as negatives
        (templated datasets repeat captions). -> (loss, top-1 accuracy of text -> motion retrieval)."""
        m, t = self.encode_motion(x, lengths), self.encode_text(sentence_emb)
        logits = t @ m.T / self.cfg.temperature                             # (B, B) text rows, motion columns
        ids = torch.as_tensor(caption_ids)
        same = (ids[:, None] == ids[None, :]) & ~torch.eye(len(ids), dtype=torch.bool)
        logits = logits.masked_fill(same, float("-inf"))
        target = torch.arange(len(ids))
        loss = 0.5 * (F.cross_entropy(logits, target) + F.cross_entropy(logits.T, target))
        return loss, (logits.argmax(-1) == target).float().mean()


class TrainedEvaluator(Evaluator):
    """A ContrastiveEvaluator checkpoint + its normalisation statistics + its frozen text encoder."""

    def __init__(self, model: ContrastiveEvaluator, mean: np.ndarray, std: np.ndarray, text_encoder=None,
                 name: str = "contrastive"):
        self.model = model.eval()
        cfg = model.cfg
        self.name, self.dim, self.unit_length, self.max_frames = name, cfg.embed_dim, cfg.unit_length, cfg.max_frames
        self.mean, self.std = np.asarray(mean, np.float32), np.asarray(std, np.float32)
        self._text_encoder = text_encoder
        self._text_cache: dict[str, np.ndarray] = {}

    @property
    def text_encoder(self):
        if self._text_encoder is None:
            from mogo_export.models.text_encoder import get_text_encoder

            self._text_encoder = get_text_encoder(self.model.cfg.text_encoder)
        return self._text_encoder

    @torch.no_grad()
    def _embed_motion_batch(self, x, lengths):
        return self.model.encode_motion(x, lengths).numpy()

    @torch.no_grad()
    def embed_texts(self, texts, tokens=None):
        todo = list(dict.fromkeys(t for t in texts if t not in self._text_cache))
        if todo:
            self._text_cache.update(zip(todo, self.text_encoder.encode(todo).float().numpy()))
        sentence = torch.from_numpy(np.stack([self._text_cache[t] for t in texts]))
        return self.model.encode_text(sentence).numpy()
