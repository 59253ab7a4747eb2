"""The env's documentation cannot drift from its code: the docstring's Arguments table is the one
generated from EnvConfig's field metadata, and the explicit ``__init__`` signature lists every argument
with EnvConfig's defaults."""

import dataclasses
import inspect

import pytest

from softpvtol_gym import SoftPVTOLEnv, SoftPVTOLVectorEnv
from softpvtol_gym.envs.config import EnvConfig, argument_rows, argument_table_markdown


def _docstring_section(title: str) -> str:
    doc = inspect.cleandoc(SoftPVTOLEnv.__doc__)
    assert f"## {title}\n" in doc, f"the env docstring has no '## {title}' section"
    return doc.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]


def test_docstring_arguments_table_is_the_generated_one():
    section = _docstring_section("Arguments")
    table = "\n".join(line for line in section.splitlines() if line.startswith("|"))
    assert table == argument_table_markdown(), (
        "the Arguments table of SoftPVTOLEnv's docstring differs from "
        "softpvtol_gym.envs.config.argument_table_markdown(); paste its output into the docstring")


def test_table_has_one_row_per_argument_with_type_default_and_description():
    table = argument_table_markdown().splitlines()
    assert table[0] == "| argument | type | default | description |"
    rows = argument_rows()
    assert len(table) == 2 + len(rows)
    assert [r[0] for r in rows] == ["render_mode"] + [f.name for f in dataclasses.fields(EnvConfig)]
    for name, type_, default, description in rows:
        assert type_ and default and len(description) > 20, name
    limits = dict((r[0], r[3]) for r in rows)["actuator_limits"]
    assert "T_max [N]" in limits and "tau_max [N m]" in limits and "102.9 N" in limits


@pytest.mark.parametrize("cls, own", [(SoftPVTOLEnv, []), (SoftPVTOLVectorEnv, ["num_envs"])])
def test_init_signature_lists_every_argument_with_envconfig_defaults(cls, own):
    """The single and the vector env: ``render_mode`` and EnvConfig's fields, in its order, with its defaults
    and annotations (the vector env also ``num_envs`` and ``autoreset_mode``): the explicit signatures (for
    editors and help()) are checked against EnvConfig, the one source of the keyword list."""
    params = inspect.signature(cls.__init__).parameters
    named = [n for n, p in params.items() if n not in ("self", "autoreset_mode") and p.kind is not p.VAR_KEYWORD]
    rows = argument_rows()
    assert named == own + [r[0] for r in rows]
    assert params["render_mode"].default is None
    for f in dataclasses.fields(EnvConfig):
        p = params[f.name]
        assert p.kind is p.KEYWORD_ONLY, f.name
        assert p.annotation == f.type, (f.name, p.annotation, f.type)  # the same type, written the same way
        expected = None if f.default_factory is not dataclasses.MISSING else f.default  # params: None -> default
        assert p.default == expected, f.name
        # the table's default is the signature's
        assert eval(f.metadata["default"]) == p.default, f.name  # noqa: S307 (our own literal)


def test_default_base_loop_is_documented_as_bounded():
    """The residual mode's default base loop is "bounded"; the docstring says so."""
    assert EnvConfig(action_mode="residual").resolved_controller_loop == "bounded"
    action = " ".join(_docstring_section("Action Space").split())
    assert 'by default "bounded"' in action
    assert '"exact" loop' not in action
