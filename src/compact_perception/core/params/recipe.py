"""A model's training recipe (:class:`ModelRecipe`): ``train.recipe`` merged with
``train.models.<id>`` (:func:`merge_recipe`), knowing where each of its values is written."""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Callable, Literal, Optional

from pydantic import ConfigDict, Field, PrivateAttr, ValidationError, field_validator, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from .base import Scaled, Strict, _scaled_at_least
from .errors import _in_params

__all__ = ["ModelRecipe", "merge_recipe", "check_lr_floor"]


def check_lr_floor(lr: float, lr_min: float) -> None:
    """The plateau halving's floor (section IV-D; MGN's weight lr too) must not exceed the lr it
    starts from."""
    if lr_min > lr:
        raise ValueError(f"lr_min ({lr_min}) must not exceed lr ({lr})")


def _plain(value: Any) -> Any:
    """``value`` as plain YAML data (dicts and lists), whatever mapping type held it."""
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def merge_recipe(base: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """The recipe ``base`` with ``changes`` applied: a key of ``changes`` replaces the base's, a
    null removes it (``momentum: null`` for an Adam recipe), and a new ``weighting`` drops the
    base's section of the weighting it replaces. Used for ``train.recipe`` + ``train.models.<id>``
    and for a study arm on its base model's recipe."""
    merged = _plain(base)
    old = merged.get("weighting")
    if "weighting" in changes and isinstance(old, str) and changes["weighting"] != old:
        merged.pop(old, None)
    merged.update(_plain(changes))
    return {k: v for k, v in merged.items() if v is not None}


def _error(key: str, value: Any, message: str) -> InitErrorDetails:
    """A validation error at ``key`` (a model validator's errors sit at the model otherwise)."""
    return InitErrorDetails(type=PydanticCustomError("recipe_key", message), loc=(key,), input=value)


def _from_base(key: str) -> str:
    """The params key of the base recipe's ``key``."""
    return f"train.recipe.{key}"


def _inherited(merged: Mapping[str, Any], changes: Mapping[str, Any], source: Callable[[str], str]) -> dict[str, str]:
    """The keys of a merged recipe that its base supplies, each with the params key holding its value."""
    return {k: source(k) for k in merged if k not in changes}


class ModelRecipe(Strict):
    """One model's training recipe (``train.recipe`` merged with ``train.models.<id>``).
    ``weighting`` names a loss weighting of the registry (``compact_perception.learning.weighting.WEIGHTINGS``);
    its settings sit in a section of the same name (``mgn: {...}``), checked against that method's
    own schema when the training or study stage starts (``weighting.weighting_settings``). Only
    the named method's section is allowed.

    A recipe read from params knows where each of its values is written (:meth:`key_of`): its
    own key, or ``train.recipe`` for what it inherits (error messages and the params audit use it)."""

    model_config = ConfigDict(extra="allow", frozen=True, strict=True)

    optimizer: Literal["sgd", "adam"]
    de_loss: Optional[Literal["huber", "smooth_l1"]] = Field(
        None, description="compact models' DE loss: 'huber' = eq. (2) with delta 0.5 (the paper), 'smooth_l1' = "
                          "torch's smooth_l1_loss(beta=0.5) = eq. (2) / delta (the authors' code); required for "
                          "the compact models, not allowed for the baselines (their own losses)")
    plateau_rule: Literal["paper", "torch"] = Field(
        description="lr halving on a validation-TM plateau (main lr and MGN's weight lr): 'paper' = after "
                    "train.plateau_patience epochs without a drop (section IV-D); 'torch' = PyTorch's "
                    "ReduceLROnPlateau as in the authors' code: after more than plateau_patience epochs without a "
                    "relative drop of train.plateau_threshold")
    lr: float = Field(gt=0.0)
    lr_min: float = Field(gt=0.0)
    momentum: Optional[float] = Field(None, ge=0.0, lt=1.0, description="SGD momentum: required with sgd, "
                                      "not allowed with adam (which has none)")
    betas: Optional[list[float]] = Field(None, description="Adam's (beta1, beta2): required with adam, "
                                         "not allowed with sgd")
    eps: Optional[float] = Field(None, gt=0.0, description="Adam's epsilon: required with adam, not allowed with sgd")
    weight_decay: float = Field(ge=0.0)
    weighting: str = Field(min_length=1, description="a loss weighting id (weighting.WEIGHTINGS)")
    max_epochs: Optional[Scaled[int]] = Field(None, description="overrides the dataset's epoch cap "
                                              "(datasets.<ds>.training.max_epochs) for this model")

    _key: str = PrivateAttr("")                                  # the params key of this recipe
    _inherited: dict[str, str] = PrivateAttr(default_factory=dict)  # key -> where its value is written

    @field_validator("max_epochs")
    @classmethod
    def _epochs(cls, v: Optional[Scaled[int]]) -> Optional[Scaled[int]]:
        return _scaled_at_least(v, 1)

    @model_validator(mode="after")
    def _optimizer_settings(self) -> "ModelRecipe":
        if self.optimizer == "sgd" and self.momentum is None:
            raise ValueError("momentum: required with optimizer 'sgd' (the paper's 0.9)")
        if self.optimizer == "adam" and self.momentum is not None:
            raise ValueError("momentum: not used by optimizer 'adam'; remove the key")
        if self.optimizer == "adam" and (self.betas is None or self.eps is None):
            raise ValueError("betas and eps: required with optimizer 'adam' (PyTorch's [0.9, 0.999] and 1.0e-8)")
        if self.optimizer == "sgd" and (self.betas is not None or self.eps is not None):
            raise ValueError("betas/eps: not used by optimizer 'sgd'; remove the keys")
        if self.betas is not None and (len(self.betas) != 2 or not all(0.0 <= b < 1.0 for b in self.betas)):
            raise ValueError(f"betas: expected two numbers in [0, 1), got {self.betas}")
        check_lr_floor(self.lr, self.lr_min)
        return self

    @model_validator(mode="after")
    def _weighting_section(self) -> "ModelRecipe":
        """Besides the schema's keys, only the section named by ``weighting``, a mapping; each error
        is placed at its key."""
        errors = []
        for key, value in (self.model_extra or {}).items():
            if key != self.weighting:
                errors.append(_error(key, value, "unknown key (not in the schema, and not the settings section "
                                                 "of the recipe's weighting)"))
            elif not isinstance(value, dict):
                errors.append(_error(key, value, "expected a mapping of the weighting's settings"))
        if errors:
            raise ValidationError.from_exception_data(type(self).__name__, errors)
        return self

    def section(self, name: str) -> dict:
        """The settings section ``name`` (the weighting's own params), ``{}`` when absent."""
        return dict((self.model_extra or {}).get(name) or {})

    @property
    def key(self) -> str:
        """The params key this recipe was read from (``train.models.<id>``, ``study.arms.<arm>``);
        ``""`` for a recipe not read from params."""
        return self._key

    def key_of(self, name: str) -> str:
        """The params key that holds this recipe's value of ``name`` (``train.recipe.lr`` for an
        inherited lr); just ``name`` for a recipe not read from params."""
        return ".".join(_in_params((name,), self._key, self._inherited))

    def placed(self, key: str, inherited: Mapping[str, str]) -> "ModelRecipe":
        """This recipe, recorded as read from params key ``key``, its ``inherited`` keys from elsewhere."""
        self._key, self._inherited = key, dict(inherited)
        return self
