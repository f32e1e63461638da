"""eval.rollout: the one episode loop -- reset order, hooks in order with the action they send,
max_steps, and how an episode ended."""
from calnav.agent.step import Step
from calnav.eval.rollout import Hook, rollout


class CountingEnv:
    """A gym-like env whose episode ends (terminated) on action 0 or after ``limit`` steps
    (truncated); obs is the step count."""

    def __init__(self, limit: int):
        self.limit, self.log = limit, []

    def reset(self, options=None):
        self.n = 0
        self.log.append(("reset", options["episode_index"]))
        return {"n": 0}, {"steps": 0}

    def step(self, action):
        self.n += 1
        self.log.append(("step", action))
        return {"n": self.n}, 0.0, action == 0, self.n >= self.limit, {"steps": self.n}


class Agent:
    def __init__(self, stop_at: int):
        self.stop_at, self.seen = stop_at, []

    def reset(self, obs):
        self.seen.append(("reset", obs["n"]))

    def act(self, obs):
        self.seen.append(("act", obs["n"]))
        return Step(0 if obs["n"] == self.stop_at else 1, len(self.seen) - 1)


class Recorder(Hook):
    def __init__(self, log, name, replace=None):
        self.log, self.name, self.replace = log, name, replace

    def on_reset(self, env, agent, obs, info):
        self.log.append((self.name, "reset", obs["n"]))

    def before_step(self, env, agent, obs, action):
        self.log.append((self.name, "before", action))
        return self.replace if self.replace is not None else action

    def after_step(self, env, agent, action, obs, info, step):
        self.log.append((self.name, "after", action, step))

    def on_end(self, env, agent, result):
        self.log.append((self.name, "end", result.steps))


def test_rollout_runs_to_stop_and_calls_hooks_in_order():
    env, agent, log = CountingEnv(limit=10), Agent(stop_at=2), []
    result = rollout(env, agent, 7, [Recorder(log, "a"), Recorder(log, "b")])
    assert env.log == [("reset", 7), ("step", 1), ("step", 1), ("step", 0)]
    assert agent.seen == [("reset", 0), ("act", 0), ("act", 1), ("act", 2)]
    assert (result.index, result.steps, result.terminated, result.truncated, result.info) == (7, 3, True, False,
                                                                                              {"steps": 3})
    assert log[:5] == [("a", "reset", 0), ("b", "reset", 0), ("a", "before", 1), ("b", "before", 1),
                       ("a", "after", 1, 1)]
    assert log[-2:] == [("a", "end", 3), ("b", "end", 3)]


def test_a_hook_replaces_the_action_and_max_steps_cuts_the_episode():
    # the agent would STOP at once; the hook sends a move instead (collect-maps' exploration),
    # and the rollout ends after max_steps, neither terminated nor truncated
    env, log = CountingEnv(limit=10), []
    result = rollout(env, Agent(stop_at=0), 0, [Recorder(log, "swap", replace=5)], max_steps=4)
    assert env.log == [("reset", 0)] + [("step", 5)] * 4
    assert (result.steps, result.terminated, result.truncated) == (4, False, False)


def test_the_env_step_limit_truncates():
    result = rollout(CountingEnv(limit=3), Agent(stop_at=-1), 0)
    assert (result.steps, result.terminated, result.truncated) == (3, False, True)
