"""calnav's Habitat-style simulator: procedural houses and labelled scans, Open3D ray-cast
rendering, a navigation grid with geodesics, ObjectNav episodes, habitat-lab's metrics and the
gymnasium environment ``calnav/ObjectNav-v0`` (registered on import)."""
from gymnasium.envs.registration import WrapperSpec, register, registry

ENV_ID = "calnav/ObjectNav-v0"

if ENV_ID not in registry:
    # EpisodeLimit hands gym.make(max_episode_steps=N) to the env (see envs.objectnav_env)
    register(id=ENV_ID, entry_point="calnav.envs.objectnav_env:ObjectNavEnv",
             additional_wrappers=(WrapperSpec("EpisodeLimit", "calnav.envs.objectnav_env:EpisodeLimit", {}),))
