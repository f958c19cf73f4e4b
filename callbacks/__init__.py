"""SB3 callbacks for trustworthy agents (transparency, safety, adversarial and fairness evaluation)."""

__all__: list[str] = []
