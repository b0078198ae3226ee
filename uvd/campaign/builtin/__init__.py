"""The built-in campaigns: the ``*.toml`` files beside this module, by their file name
(``uvd campaign fdc-detection``); a path names a campaign file of one's own."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from uvd.campaign.spec import CampaignError, CampaignSpec, load, parse


def _kinds():
    from uvd.campaign.runs import kind_axes
    return kind_axes()


def names() -> list[str]:
    return sorted(f.name[:-5] for f in files(__name__).iterdir() if f.name.endswith(".toml"))


def campaigns() -> dict[str, CampaignSpec]:
    """Every built-in campaign, validated."""
    return {n: resolve(n) for n in names()}


def resolve(name_or_path: str | Path) -> CampaignSpec:
    """A built-in campaign by name, or a campaign file by path."""
    import tomllib
    text = str(name_or_path)
    if text in names():
        res = files(__name__) / f"{text}.toml"
        return parse(tomllib.loads(res.read_text()), _kinds(), source=f"built-in {text}")
    path = Path(text)
    if not path.exists() and not text.endswith(".toml"):
        raise CampaignError(f"{text!r}: neither a campaign file nor a built-in campaign "
                            f"({', '.join(names())})")
    return load(path, _kinds())
