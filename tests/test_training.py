"""The training env (sim2real/policies/envs.py) and the PPO-to-checkpoint conversion (sim2real/policies/train.py)."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from sim2real.deploy.policy.mlp_checkpoint import load_checkpoint, save_checkpoint
from sim2real.eval.world.dynamics import DynamicsRanges
from sim2real.policies.envs import ArmReachEnv, ReachConfig, ReachTask, RewardConfig

NOMINAL = ReachConfig(dynamics=DynamicsRanges.none())


def test_the_env_passes_gymnasiums_checker(arm3):
    env = ArmReachEnv(arm3, NOMINAL, seed=0)
    check_env(env, skip_render_check=True)


def test_observations_are_the_runtimes_spec_applied_to_the_filtered_state(arm3):
    task = ReachTask(arm3, 2, NOMINAL, seed=1)
    for _ in range(20):
        obs, *_ = task.step(np.full((2, 3), 0.5))
    expected = task.spec.observation(task.state, task.goal)
    np.testing.assert_array_equal(obs, expected)
    # the state is the Kalman estimate of noisy encoders, not the simulator's truth
    assert not np.array_equal(task.state.q, task.backend.true_position())
    np.testing.assert_allclose(task.state.q, task.backend.true_position(), atol=0.05)


def test_reaching_the_goal_pays_the_success_reward_and_draws_a_new_goal(arm3):
    task = ReachTask(arm3, 1, NOMINAL, seed=2)
    q = arm3.home.copy()
    task.goal[0] = arm3.forward_kinematics(q)  # the goal is where the arm already is
    task.backend.reset(q)
    old_goal = task.goal[0].copy()
    _, reward, terminated, _ = task.step(np.zeros((1, 3)))
    assert reward[0] > 0.9  # +1 success, tiny penalties
    assert task.task.reached[0] == 1 and not terminated[0]
    assert not np.array_equal(task.goal[0], old_goal)


def test_a_hard_limit_terminates_the_episode_with_the_hard_penalty(arm3):
    # The smoother brakes velocity commands before the limits, so a policy meets a hard limit
    # only through overshoot or a push; put the shoulder past its limit directly.
    reward = RewardConfig(shaping=0.0)
    task = ReachTask(arm3, 1, ReachConfig(dynamics=DynamicsRanges.none(), reward=reward), seed=3)
    _, r, terminated, _ = task.step(np.zeros((1, 3)))
    assert not terminated[0] and abs(r[0]) < 0.05
    task.backend.datas[0].qpos[0] = arm3.position_upper[0] + 0.1
    _, r, terminated, truncated = task.step(np.zeros((1, 3)))
    assert terminated[0] and not truncated[0]
    assert -1.2 < r[0] < -0.9  # -1 hard limit, -0.1 for the soft band it is also in
    assert task.episode_info(0)["joint_limit_violations"] == 1


def test_pushing_a_joint_into_its_soft_limit_is_an_intervention_and_costs_its_penalty(arm3):
    """The runtime's guard and smoother brake the joint at the soft limit, so the joint never
    enters the band (no soft-band penalty); a policy that keeps driving it there is charged the
    intervention penalty every tick, and the episode's intervention rate shows it."""
    reward = RewardConfig(
        shaping=0.0,
        energy=0.0,
        heat=0.0,
        jerk=0.0,
        survival=0.0,
        intervention=-0.3,
        soft_limit=-0.1,
    )
    cfg = ReachConfig(dynamics=DynamicsRanges.none(), reward=reward)
    task = ReachTask(arm3, 2, cfg, seed=7)
    action = np.zeros((2, 3))
    action[1, 2] = 1.0  # env 1 drives its wrist toward the upper limit at full speed
    rewards = np.array([task.step(action)[1] for _ in range(300)])  # 1.5 s
    q = task.backend.true_position()
    assert q[1, 2] <= arm3.soft_upper[2] + 0.02  # braked at the soft limit
    assert q[1, 2] > arm3.soft_upper[2] - 0.05  # and resting near it
    pushing = rewards[-100:]  # at rest at the limit, still pushing
    np.testing.assert_allclose(pushing[:, 1], -0.3, atol=1e-9)
    assert np.abs(pushing[:, 0]).max() < 1e-9  # env 0 holds still: no penalty
    assert task.episode_info(1)["intervention_rate"] > 0.3
    assert task.episode_info(0)["intervention_rate"] == 0.0
    assert task.guard.counts["velocity"][1] > 0  # the runtime's guard is in the loop


def test_episodes_draw_noise_and_dynamics_per_env(arm3):
    task = ReachTask(arm3, 4, ReachConfig(), seed=4)
    lo, hi = task.config.sensors.noise_sigma  # the robot's soak ranges
    assert np.all((task.backend.noise_sigma >= lo) & (task.backend.noise_sigma <= hi))
    assert len({d.mass for d in task.dynamics}) == 4  # one draw per env
    masses = [m.body_mass[m.jnt_bodyid[0]] for m in task.backend.models]
    assert len(set(masses)) == 4
    before = task.dynamics[1]
    task.reset(np.array([False, True, False, False]))
    assert task.dynamics[1] != before and task.dynamics[0] is not before


def test_the_shipped_checkpoint_holds_the_ppo_mean_action(arm3, tmp_path):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from sim2real.policies.train import HIDDEN, ReachVecEnv, actor_from_model

    task = ReachTask(arm3, 2, NOMINAL, seed=5)
    model = PPO(
        "MlpPolicy",
        ReachVecEnv(task),
        n_steps=8,
        batch_size=16,
        policy_kwargs={"net_arch": {"pi": list(HIDDEN), "vf": [8]}, "activation_fn": torch.nn.Tanh},
        seed=0,
        device="cpu",
    )
    model.learn(16)
    actor = actor_from_model(model)
    path = save_checkpoint(tmp_path / "arm.pt", actor, task.spec)
    loaded, spec, _ = load_checkpoint(path)
    obs = np.random.default_rng(0).uniform(-1, 1, (32, task.spec.obs_dim)).astype(np.float32)
    expected, _ = model.predict(obs, deterministic=True)  # SB3 clips to the action space
    with torch.no_grad():
        got = loaded(torch.from_numpy(obs)).numpy().clip(-1, 1)
    np.testing.assert_allclose(got, expected, atol=1e-6)
    assert spec == task.spec


def test_a_vec_env_reset_keeps_the_terminal_observation(arm3):
    pytest.importorskip("stable_baselines3")
    from sim2real.policies.train import ReachVecEnv

    cfg = ReachConfig(dynamics=DynamicsRanges.none(), episode_seconds=0.05)  # 10 ticks
    venv = ReachVecEnv(ReachTask(arm3, 2, cfg, seed=6))
    venv.reset()
    for _ in range(10):
        venv.step_async(np.zeros((2, 3)))
        obs, _, dones, infos = venv.step_wait()
    assert dones.all()
    for e in range(2):
        assert infos[e]["TimeLimit.truncated"] is True
        assert "joint_limit_violations" in infos[e] and "is_success" in infos[e]
        assert not np.array_equal(infos[e]["terminal_observation"], obs[e])


def test_episodes_start_at_the_given_missed_poses(arm3):
    pose = (0.3, -1.2, 1.0)
    cfg = ReachConfig(
        dynamics=DynamicsRanges.none(),
        start_poses=(pose, (0.0, 5.0, 0.0)),
        start_pose_probability=1.0,
    )
    task = ReachTask(arm3, 8, cfg, seed=8)
    q = task.backend.true_position()
    listed = np.array([pose, np.clip((0.0, 5.0, 0.0), arm3.soft_lower, arm3.soft_upper)])
    # every env starts at one of the poses, clipped into the soft limits
    assert all(np.isclose(q[e], listed, atol=1e-9).all(axis=1).any() for e in range(8))
    assert {tuple(row) for row in q.round(6)} == {tuple(row) for row in listed.round(6)}


def test_training_ships_only_a_policy_that_passes_the_soak(tmp_path):
    """An untrained policy fails the shipping soak: the candidate and the soak's report stay in
    the log folder, with the soak's film (the soak command's default: the film of a session
    run through soak-test's main, asserted here), and --out is not written."""
    pytest.importorskip("stable_baselines3")
    from sim2real.policies.train import main

    out = tmp_path / "ship" / "arm.pt"
    args = ["--steps", "256", "--envs", "2", "--n-steps", "64", "--batch-size", "64"]
    args += ["--anneal-steps", "0", "--logdir", str(tmp_path), "--out", str(out), "--no-progress"]
    code = main(args + ["--gate-hours", "0.0015", "--gate-sessions", "1"])  # 5.4 s, one goal
    assert code == 1
    assert not out.exists()
    assert (tmp_path / "arm3_velocity_seed1.pt").exists()
    gate = tmp_path / "arm3_velocity_seed1.gate"
    (session,) = json.loads((gate / "report.json").read_text())["sessions"]
    film = session["film"]
    assert film["error"] is None and film["clips"]
    assert all((gate / c["video"]).is_file() for c in film["clips"])
    assert main(args + ["--gate-hours", "0"]) == 0  # without the gate it ships
    assert out.exists() and out.with_suffix(".curve.json").exists()


def test_fine_tuning_the_shipped_arm_starts_from_its_actor_and_warms_the_critic_first(tmp_path):
    """--init-from sim2real/policies/arm.pt starts PPO's mean at the shipped actor: a run that is all critic
    warm-up writes a candidate equal to arm.pt; after the warm-up the actor learns; another
    robot's checkpoint is refused with the file named."""
    pytest.importorskip("stable_baselines3")
    from sim2real.policies.train import main

    shipped = load_checkpoint("sim2real/policies/arm.pt")[0].state_dict()
    common = ["--envs", "2", "--n-steps", "16", "--batch-size", "16", "--epochs", "1"]
    common += ["--anneal-steps", "0", "--no-progress", "--gate-hours", "0"]
    common += [
        "--init-from",
        "sim2real/policies/arm.pt",
        "--out",
        str(tmp_path / "ship" / "arm.pt"),
    ]
    main(common + ["--steps", "32", "--critic-warmup", "32", "--logdir", str(tmp_path / "w")])
    warmed = load_checkpoint(tmp_path / "w" / "arm3_velocity_seed1.pt")[0].state_dict()
    assert shipped.keys() == warmed.keys()
    for key in shipped:
        torch.testing.assert_close(warmed[key], shipped[key], rtol=0, atol=0)

    main(common + ["--steps", "64", "--critic-warmup", "32", "--logdir", str(tmp_path / "t")])
    tuned = load_checkpoint(tmp_path / "t" / "arm3_velocity_seed1.pt")[0].state_dict()
    assert any(not torch.equal(tuned[k], shipped[k]) for k in shipped)

    with pytest.raises(ValueError, match=r"so101\.pt.*spec"):
        main(common[:-4] + ["--init-from", "sim2real/policies/so101.pt", "--steps", "16"])


def test_fine_tuning_a_hard_range_checkpoint_keeps_its_targets_inside_the_soft_limits(tmp_path):
    """A position policy trained when a full absolute action was the hard limit (today's
    ``position_range="hard"``) fine-tunes under the default soft range: the output layer is
    rescaled, so a run that is all critic warm-up gives the same targets, clipped to the soft
    limits (where the old policy saturated, as so101's gripper did, the new one rests on the
    soft limit, which the guard does not clamp)."""
    pytest.importorskip("stable_baselines3")
    from sim2real.deploy.spec.policy_spec import PolicySpec
    from sim2real.policies.train import main
    from sim2real.robots import load_robot

    so101 = load_robot("so101")
    actor = load_checkpoint("sim2real/policies/so101.pt")[0]
    hard = PolicySpec.for_robot(so101, mode="position", position_range="hard")
    save_checkpoint(tmp_path / "hard.pt", actor, hard)
    args = ["--robot", "so101", "--mode", "position", "--envs", "2", "--n-steps", "16"]
    args += ["--batch-size", "16", "--epochs", "1", "--anneal-steps", "0", "--no-progress"]
    args += ["--gate-hours", "0", "--init-from", str(tmp_path / "hard.pt"), "--steps", "32"]
    args += ["--critic-warmup", "32", "--logdir", str(tmp_path / "w")]
    main(args + ["--out", str(tmp_path / "ship" / "so101.pt")])
    tuned, spec, _ = load_checkpoint(tmp_path / "w" / "so101_position_seed1.pt")
    assert spec.to_json() == PolicySpec.for_robot(so101, mode="position").to_json()
    obs = torch.as_tensor(np.random.default_rng(0).normal(0, 1, (512, spec.obs_dim)))
    with torch.no_grad():
        before = actor(obs.float()).numpy().clip(-1, 1) * hard.action.scale + hard.action.offset
        after = tuned(obs.float()).numpy().clip(-1, 1) * spec.action.scale + spec.action.offset
    np.testing.assert_allclose(after, before.clip(so101.soft_lower, so101.soft_upper), atol=1e-5)
    assert (before < so101.soft_lower).any() or (before > so101.soft_upper).any()


def test_holding_the_arm_against_gravity_costs_its_joule_heat(arm3):
    """The heat term charges sum (tau / continuous_torque)^2: the stretched arm, held against
    gravity at rest, costs more than the arm hanging down, and exactly the formula's amount."""
    reward = RewardConfig(
        shaping=0.0, energy=0.0, jerk=0.0, survival=0.0, success=0.0, soft_limit=0.0, heat=1e-3
    )
    cfg = ReachConfig(dynamics=DynamicsRanges.none(), reward=reward, start_pose_probability=1.0)
    stretched, hanging = (0.0, 0.0, 0.0), (-1.3, 0.0, 0.0)
    costs = {}
    for name, pose in (("stretched", stretched), ("hanging", hanging)):
        task = ReachTask(arm3, 1, replace(cfg, start_poses=(pose,)), seed=9)
        for _ in range(200):  # 1 s at rest: the drives settle on the gravity torque
            _, r, *_ = task.step(np.zeros((1, 3)))
        tau = task.backend.joint_torque()[0]
        continuous = np.array([m.continuous_torque for m in arm3.motors])
        np.testing.assert_allclose(r[0], -1e-3 * np.sum((tau / continuous) ** 2), rtol=1e-9)
        costs[name] = -r[0]
    assert costs["stretched"] > 5 * costs["hanging"]


def test_the_shipped_so101_policy_reaches_its_goals_through_the_runtime(tmp_path):
    """sim2real/policies/so101.pt (make train ROBOT=so101), exported with its parity gate, through the
    full runtime on the sim backend: the goals of a minute reached (the issue asks >= 90 % over
    longer runs; 60 s has 15 goals), no hard violation, a clean exit."""
    import json

    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.deploy.cli.policy_export import main as export_main

    onnx = tmp_path / "so101.onnx"
    assert export_main(["sim2real/policies/so101.pt", "--out", str(onnx)]) == 0
    report = tmp_path / "run.json"
    code = deploy_run_main(
        ["--robot", "so101", "--policy", str(onnx), "--duration", "60", "--report", str(report)]
    )
    r = json.loads(report.read_text())
    assert code == 0 and r["final_state"] == ["RUNNING"]
    assert r["goals"]["success_rate"] >= 13 / 15
    assert r["violations"]["by_type"]["hard_limit"] == 0
