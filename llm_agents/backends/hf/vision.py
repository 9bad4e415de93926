"""Image-text models in the hf backend: a model folder whose config has a vision tower
(`vision_config`: Llava, Qwen2-VL, Idefics, SmolVLM, ...) is loaded with transformers'
`AutoModelForImageTextToText` and its `AutoProcessor`, which renders each conversation with
the processor's chat template (an image part where each image goes) and turns the images into
the model's pixel inputs.

Every conversation such a model answers goes through its processor, with or without images;
`loglik` choices stay with text models (the choice is refused with images by the run's
settings).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import torch
from transformers import AutoModelForImageTextToText, AutoProcessor

from llm_agents.backends.base import Conversation, GenerateConfig, ModelOutput
from llm_agents.backends.reasoning import with_reasoning_split


def is_image_text(model_config: Any) -> bool:
    """Whether a transformers config is an image-text model's (it has a vision tower)."""
    return getattr(model_config, "vision_config", None) is not None


def load_processor(source: str) -> Any:
    return AutoProcessor.from_pretrained(source, local_files_only=True)


def load_model(source: str, dtype: torch.dtype) -> Any:
    return AutoModelForImageTextToText.from_pretrained(source, local_files_only=True, dtype=dtype)


def processor_messages(conversation: Conversation) -> list[dict[str, Any]]:
    """A conversation as a processor's chat template takes it: each message's images (PIL)
    as image parts, then its text."""
    return [
        {
            "role": message.role,
            "content": [
                *({"type": "image", "image": image.pil()} for image in message.images),
                {"type": "text", "text": message.content},
            ],
        }
        for message in conversation
    ]


def generate(
    model: Any,
    processor: Any,
    conversations: Sequence[Conversation],
    config: GenerateConfig,
    device: torch.device,
    dtype: torch.dtype,
) -> list[ModelOutput]:
    """Answer a batch of conversations (left-padded, one `generate` call)."""
    start = time.perf_counter()
    tokenizer = processor.tokenizer
    tokenizer.padding_side = "left"
    if tokenizer.pad_token_id is None:
        tokenizer.pad_token = tokenizer.eos_token
    inputs = processor.apply_chat_template(
        [processor_messages(conversation) for conversation in conversations],
        add_generation_prompt=True,
        tokenize=True,
        return_dict=True,
        return_tensors="pt",
        processor_kwargs={"padding": True},
    )
    inputs = {
        name: value.to(device, dtype) if value.is_floating_point() else value.to(device)
        for name, value in inputs.items()
        if isinstance(value, torch.Tensor)
    }
    sampling: dict[str, Any] = {"do_sample": False}
    if config.temperature > 0:
        sampling = {"do_sample": True, "temperature": config.temperature, "top_p": config.top_p}
        if config.sampling_seed is not None:
            torch.manual_seed(config.sampling_seed)
    with torch.inference_mode():
        generated = model.generate(
            **inputs,
            max_new_tokens=config.max_tokens,
            pad_token_id=tokenizer.pad_token_id,
            stop_strings=config.stop or None,
            tokenizer=tokenizer if config.stop else None,
            **sampling,
        )
    latency = time.perf_counter() - start
    prompt_len = inputs["input_ids"].shape[1]
    eos = _eos_ids(model, tokenizer)
    outputs = []
    for row, mask in zip(generated[:, prompt_len:], inputs["attention_mask"], strict=True):
        tokens = row.tolist()
        ended = next((i for i, token in enumerate(tokens) if token in eos), None)
        if ended is not None:
            tokens = tokens[:ended]
        text = str(tokenizer.decode(tokens, skip_special_tokens=True))
        stopped = next((text.find(s) for s in config.stop if s in text), None)
        if stopped is not None:
            text = text[:stopped]
        output = ModelOutput(
            text=text,
            prompt_tokens=int(mask.sum()),
            completion_tokens=len(tokens) + (ended is not None),
            latency_s=latency,
            finish_reason="stop" if ended is not None or stopped is not None else "length",
        )
        outputs.append(with_reasoning_split(output, thinking_open_in_prompt=False))
    return outputs


def _eos_ids(model: Any, tokenizer: Any) -> set[int]:
    configured = model.generation_config.eos_token_id
    ids = configured if isinstance(configured, list) else [configured]
    return {i for i in [*ids, tokenizer.eos_token_id] if i is not None}
