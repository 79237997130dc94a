"""Environments shipped with digail, registered with Gymnasium on `import digail`."""

from digail.envs.registry import make_env, register_envs

__all__ = ["make_env", "register_envs"]
