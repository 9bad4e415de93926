"""The two Craftax variants CrafText runs on."""

from enum import StrEnum

from env import craftax_names
from env.errors import UserError


class Variant(StrEnum):
    """`full`: Craftax (43 actions, 9 floors); `classic`: Craftax-Classic (17 actions)."""

    FULL = "full"
    CLASSIC = "classic"

    @property
    def craftax_name(self) -> str:
        """The craftax environment id this variant wraps."""
        return "Craftax-Symbolic-v1" if self is Variant.FULL else "Craftax-Classic-Symbolic-v1"

    @property
    def action_names(self) -> tuple[str, ...]:
        """craftax `Action` names of the variant by id."""
        if self is Variant.FULL:
            return craftax_names.FULL_ACTIONS
        return craftax_names.CLASSIC_ACTIONS

    @property
    def achievement_names(self) -> tuple[str, ...]:
        """craftax `Achievement` names of the variant by id."""
        if self is Variant.FULL:
            return craftax_names.FULL_ACHIEVEMENTS
        return craftax_names.CLASSIC_ACHIEVEMENTS

    @property
    def block_names(self) -> tuple[str, ...]:
        """craftax `BlockType` names of the variant by id."""
        if self is Variant.FULL:
            return craftax_names.FULL_BLOCKS
        return craftax_names.CLASSIC_BLOCKS

    @property
    def num_actions(self) -> int:
        return len(self.action_names)


#: The variant the env, the settings and the `default` protocol start from.
DEFAULT_VARIANT = Variant.FULL


def as_variant(variant: Variant | str) -> Variant:
    """Accept a `Variant` or its value (`"full"`, `"classic"`); anything else is a `UserError`."""
    try:
        return Variant(variant)
    except ValueError:
        known = ", ".join(v.value for v in Variant)
        raise UserError(f"unknown variant {variant!r}; known: {known}") from None
