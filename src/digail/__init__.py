"""digail: Directed-Info GAIL (Sharma et al., ICLR 2019).

Learns, from unsegmented expert demonstrations, a segmentation into sub-tasks, one policy per sub-task and a
macro-policy that switches between them. Importing the package registers its Gymnasium environments.
"""

from digail.data.trajectory import Trajectory
from digail.envs import register_envs as _register_envs
from digail.errors import UserError
from digail.version import __version__

_register_envs()

__all__ = ["Trajectory", "UserError", "__version__"]
