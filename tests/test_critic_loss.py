"""CalQLLoss, tested the TorchRL way: tiny networks, gradient isolation per term, no input mutation,
state_dict round trip; plus the two places where it departs from the stock CQLLoss (the logsumexp's
axis, every sampled action scored at s) and Cal-QL's calibration on hand-made numbers."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.objectives import SoftUpdate

from critics import CalQLLoss, TanhGaussianActor, TwinQNetwork, cql_logsumexp
from critics.data import NO_FLOOR

OBS, ACT, BATCH, N = 5, 3, 6, 4


# The loss settings these tests were written against: plain Cal-QL (CQL weight 5, the policy's backup,
# TD alone, squared error); each test sets what it examines on top.
CAL_QL = dict(
    n_actions=N,
    gamma=0.9,
    cql_weight=5.0,
    temperature=1.0,
    calibrate=True,
    with_lagrange=False,
    target_action_gap=0.8,
    backup="policy",
    mc_weight=0.0,
    value_loss="mse",
)


def make_loss(seed: int = 0, **kwargs) -> CalQLLoss:
    torch.manual_seed(seed)
    return CalQLLoss(TanhGaussianActor(OBS, ACT, (8,)), TwinQNetwork(OBS, ACT, (8, 8)), **{**CAL_QL, **kwargs})


def make_batch(seed: int = 1, mc_return: float | None = None) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    mc = torch.rand(BATCH, 1, generator=g) if mc_return is None else torch.full((BATCH, 1), mc_return)
    return TensorDict(
        {
            "observation": torch.randn(BATCH, OBS, generator=g),
            "action": torch.rand(BATCH, ACT, generator=g) * 2 - 1,
            "mc_return": mc,
            "next": {
                "observation": torch.randn(BATCH, OBS, generator=g),
                "reward": torch.rand(BATCH, 1, generator=g),
                "terminated": torch.tensor([[True], [False]] * (BATCH // 2)),
            },
        },
        batch_size=[BATCH],
    )


def param_groups(loss: CalQLLoss) -> dict[str, list[torch.Tensor]]:
    groups = {
        "actor": list(loss.actor_network_params.values(True, True)),
        "critic": list(loss.qvalue_network_params.values(True, True)),
        "alpha": [loss.log_alpha],
    }
    if loss.with_lagrange:
        groups["alpha_prime"] = [loss.log_alpha_prime]
    return groups


@pytest.mark.parametrize(
    "term, owner",
    [
        ("loss_actor", "actor"),
        ("loss_qvalue", "critic"),
        ("loss_cql", "critic"),
        ("loss_alpha", "alpha"),
        ("loss_alpha_prime", "alpha_prime"),
    ],
)
def test_each_term_sends_gradients_only_to_its_own_parameters(term, owner):
    loss = make_loss(with_lagrange=True)
    out = loss(make_batch())
    out[term].backward()
    for name, params in param_groups(loss).items():
        touched = any(p.grad is not None and p.grad.abs().sum() > 0 for p in params)
        assert touched == (name == owner), (term, name)
    assert all(not p.requires_grad for p in loss.target_qvalue_network_params.values(True, True))


def test_input_tensordict_is_not_mutated():
    batch = make_batch()
    before = batch.clone()
    make_loss()(batch)
    assert set(batch.keys(True, True)) == set(before.keys(True, True))
    assert (batch == before).all()


def test_state_dict_round_trips():
    trained = make_loss(seed=0, with_lagrange=True)
    other = make_loss(seed=5, with_lagrange=True)
    batch = make_batch()
    opt = torch.optim.SGD(trained.parameters(), lr=0.1)
    sum(v for k, v in trained(batch).items() if k.startswith("loss_")).backward()
    opt.step()
    other.load_state_dict(trained.state_dict())
    for key, value in trained.state_dict().items():
        assert torch.equal(value, other.state_dict()[key]), key
    torch.manual_seed(3)
    a = trained(batch)
    torch.manual_seed(3)
    b = other(batch)
    assert all(torch.equal(a[k], b[k]) for k in a.keys())


def test_logsumexp_is_over_each_states_sampled_actions():
    g = torch.Generator().manual_seed(0)
    critics, states, n_uniform, n_policy, action_dim = 2, 3, 4, 8, 7
    q_uniform = torch.randn(critics, states, n_uniform, generator=g, dtype=torch.float64)
    q_policy = torch.randn(critics, states, n_policy, generator=g, dtype=torch.float64)
    log_prob = torch.randn(states, n_policy, generator=g, dtype=torch.float64)
    got = cql_logsumexp(q_uniform, q_policy, log_prob, None, action_dim=action_dim, temperature=2.0)
    assert got.shape == (critics, states)
    for c in range(critics):
        for s in range(states):
            values = [(q_uniform[c, s, j].item() - action_dim * math.log(0.5)) / 2.0 for j in range(n_uniform)]
            values += [(q_policy[c, s, j].item() - log_prob[s, j].item()) / 2.0 for j in range(n_policy)]
            assert got[c, s].item() == pytest.approx(2.0 * math.log(sum(math.exp(v) for v in values)), rel=1e-12)


def test_calibration_clips_policy_q_from_below_by_the_mc_return():
    # one critic, two states, one uniform action and two policy actions each
    q_uniform = torch.tensor([[[0.0], [1.0]]], dtype=torch.float64)
    q_policy = torch.tensor([[[-5.0, 2.0], [4.0, 6.0]]], dtype=torch.float64)
    log_prob = torch.zeros(2, 2, dtype=torch.float64)
    mc_return = torch.tensor([3.0, 1.0], dtype=torch.float64)
    got = cql_logsumexp(q_uniform, q_policy, log_prob, mc_return, action_dim=1)
    uniform = -math.log(0.5)  # subtracting log density 0.5 on [-1, 1]
    # state 0: -5 and 2 are both below the return 3 and lifted to it; state 1: 4 and 6 are above 1, unchanged
    assert got[0, 0].item() == pytest.approx(math.log(math.exp(0 + uniform) + 2 * math.exp(3.0)))
    assert got[0, 1].item() == pytest.approx(math.log(math.exp(1 + uniform) + math.exp(4.0) + math.exp(6.0)))
    plain = cql_logsumexp(q_uniform, q_policy, log_prob, None, action_dim=1)
    assert plain[0, 0].item() == pytest.approx(math.log(math.exp(uniform) + math.exp(-5.0) + math.exp(2.0)))
    assert plain[0, 1].item() == pytest.approx(got[0, 1].item())


def action_blind(loss: CalQLLoss) -> CalQLLoss:
    """Zero the critics' action weights (and the targets'), so Q(s, a) depends on s only."""
    with torch.no_grad():
        loss.qvalue_network_params["action_weight"].zero_()
        loss.target_qvalue_network_params["action_weight"].zero_()
    return loss


def test_every_sampled_action_is_scored_at_s():
    loss = action_blind(make_loss())
    terms = loss.terms(make_batch())
    # Q ignores the action: if the pi(.|s') actions were scored at s' (as the stock CQLLoss does),
    # they would differ from Q(s, a_data); scored at s they all equal it.
    assert terms.q_policy.shape == (2, BATCH, 2 * N) and terms.q_uniform.shape == (2, BATCH, N)
    assert torch.allclose(terms.q_policy, terms.q_data.unsqueeze(-1).expand_as(terms.q_policy))
    assert torch.allclose(terms.q_uniform, terms.q_data.unsqueeze(-1).expand_as(terms.q_uniform))


def test_calibration_inside_the_module():
    calibrated, plain = action_blind(make_loss(calibrate=True)), action_blind(make_loss(calibrate=False))
    for mc, raises_loss in ((100.0, True), (-100.0, False)):
        torch.manual_seed(7)
        a = calibrated(make_batch(mc_return=mc))
        torch.manual_seed(7)
        b = plain(make_batch(mc_return=mc))
        assert (a["loss_cql"] > b["loss_cql"] + 1.0) if raises_loss else torch.equal(a["loss_cql"], b["loss_cql"])
        assert a["calibrated_fraction"].item() == (1.0 if raises_loss else 0.0)


def test_td_target_bootstraps_only_from_non_terminal_states():
    loss = action_blind(make_loss())
    batch = make_batch()
    terms = loss.terms(batch)
    with torch.no_grad(), loss.target_qvalue_network_params.data.to_module(loss.qvalue_network):
        next_q = loss.qvalue_network(batch["next", "observation"], torch.zeros(BATCH, 1, ACT)).amin(0).squeeze(-1)
    reward, terminated = batch["next", "reward"].squeeze(-1), batch["next", "terminated"].squeeze(-1)
    expected = torch.where(terminated, reward, reward + 0.9 * next_q)
    assert torch.allclose(terms.target, expected)


def test_dataset_backup_bootstraps_from_the_datasets_next_action_not_the_actor():
    batch = make_batch()
    batch["next", "action"] = torch.rand(BATCH, ACT, generator=torch.Generator().manual_seed(5)) * 2 - 1
    loss = make_loss(backup="dataset")
    assert ("next", "action") in loss.in_keys and ("next", "action") not in make_loss().in_keys
    terms = loss.terms(batch)
    with torch.no_grad(), loss.target_qvalue_network_params.data.to_module(loss.qvalue_network):
        next_q = (
            loss.qvalue_network(batch["next", "observation"], batch["next", "action"].unsqueeze(1)).amin(0).squeeze(-1)
        )
    reward, terminated = batch["next", "reward"].squeeze(-1), batch["next", "terminated"].squeeze(-1)
    assert torch.allclose(terms.target, torch.where(terminated, reward, reward + 0.9 * next_q))
    with torch.no_grad():  # the actor does not enter the target
        for p in loss.actor_network_params.values(True, True):
            p.add_(1.0)
    assert torch.allclose(loss.terms(batch).target, terms.target)
    # while the policy backup ignores the dataset's next action
    policy = make_loss()
    torch.manual_seed(3)
    before = policy.terms(batch).target
    batch["next", "action"] = -batch["next", "action"]
    torch.manual_seed(3)
    assert torch.allclose(policy.terms(batch).target, before)
    with pytest.raises(ValueError, match="backup must be one of policy, dataset"):
        make_loss(backup="expectile")


def test_soft_update_moves_targets_towards_the_critics():
    loss = make_loss()
    updater = SoftUpdate(loss, tau=0.25)
    with torch.no_grad():
        loss.qvalue_network_params["first_bias"].add_(1.0)
    before = loss.target_qvalue_network_params["first_bias"].clone()
    updater.step()
    after = loss.target_qvalue_network_params["first_bias"]
    assert torch.allclose(after, before + 0.25 * (loss.qvalue_network_params["first_bias"] - before))


def test_keys_are_configurable():
    loss = make_loss()
    batch = make_batch().rename_key_("observation", "obs").rename_key_(("next", "observation"), ("next", "obs"))
    loss.set_keys(observation="obs")
    assert "obs" in loss.in_keys
    assert set(loss(batch).keys()) == set(loss.out_keys)
    with pytest.raises(ValueError):
        loss.set_keys(not_a_key="x")


@pytest.mark.parametrize("hidden, batch", [((8, 8), 40), ((6, 5, 4), 17)])
def test_fused_critic_pass_matches_autograd(hidden, batch):
    """The twin critic's hand-written chunked backward (used when only the weights need gradients)
    gives autograd's gradients; batches that are not a multiple of the chunk size included."""
    torch.manual_seed(0)
    net = TwinQNetwork(OBS, ACT, hidden).double()
    obs = torch.randn(batch, OBS, dtype=torch.float64)
    actions = torch.rand(batch, 31, ACT, dtype=torch.float64) * 2 - 1
    weight = torch.randn(2, batch, 31, dtype=torch.float64)
    (net(obs, actions) * weight).sum().backward()  # fused: inputs need no gradient
    fused = [p.grad.clone() for p in net.parameters()]
    net.zero_grad()
    q = net(obs, actions.clone().requires_grad_())  # autograd: the actions need a gradient
    (q * weight).sum().backward()
    assert q.grad_fn.name() != "_FusedTwinMLPBackward"
    for a, b in zip(fused, (p.grad for p in net.parameters())):
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-12)


def test_multi_step_transitions_discount_the_bootstrap_by_gamma_to_the_steps():
    loss = action_blind(make_loss())
    batch = make_batch()
    batch["steps_to_next_obs"] = torch.tensor([[1], [3]] * (BATCH // 2))
    terms = loss.terms(batch)
    with torch.no_grad(), loss.target_qvalue_network_params.data.to_module(loss.qvalue_network):
        next_q = loss.qvalue_network(batch["next", "observation"], torch.zeros(BATCH, 1, ACT)).amin(0).squeeze(-1)
    reward, terminated = batch["next", "reward"].squeeze(-1), batch["next", "terminated"].squeeze(-1)
    discount = 0.9 ** batch["steps_to_next_obs"].squeeze(-1).float()
    assert torch.allclose(terms.target, torch.where(terminated, reward, reward + discount * next_q))
    assert not torch.allclose(terms.target, loss.terms(make_batch()).target)


def test_mc_weight_adds_the_regression_on_known_monte_carlo_returns_only():
    batch = make_batch()
    batch["mc_return"][:2] = NO_FLOOR  # no return known for the first two rows
    plain, with_mc = make_loss(), make_loss(mc_weight=2.0)  # same seed: the same networks
    terms = plain.terms(batch)
    td, _ = plain.qvalue_loss(batch, terms)
    combined, _ = with_mc.qvalue_loss(batch, terms)
    known = batch["mc_return"].squeeze(-1)[2:]
    expected = td + 2.0 * (terms.q_data[:, 2:] - known).pow(2).mean(-1).sum(0)
    assert combined.item() == pytest.approx(expected.item(), rel=1e-6) and combined.item() > td.item()


def test_bce_value_loss_classifies_logits_against_target_probabilities_and_floors_with_logits():
    batch = make_batch(mc_return=0.5)  # rewards in [0, 1): probabilities
    batch["next", "action"] = torch.rand(BATCH, ACT) * 2 - 1
    loss = make_loss(value_loss="bce", backup="dataset")
    terms = loss.terms(batch)
    with torch.no_grad():
        logits = loss._q(
            loss.target_qvalue_network_params.data, batch["next", "observation"], batch["next", "action"].unsqueeze(1)
        )
    alive = ~batch["next", "terminated"].squeeze(-1)
    # the TD target backs up a probability, sigmoid of the smaller target logit, not the logit itself
    expected_target = batch["next", "reward"].squeeze(-1) + 0.9 * alive * torch.sigmoid(logits.amin(0).squeeze(-1))
    assert torch.allclose(terms.target, expected_target)
    value, _ = loss.qvalue_loss(batch, terms)
    expected = (
        torch.nn.functional.binary_cross_entropy_with_logits(
            terms.q_data, terms.target.clamp(0, 1).expand_as(terms.q_data), reduction="none"
        )
        .mean(-1)
        .sum(0)
    )
    assert value.item() == pytest.approx(expected.item(), rel=1e-6)
    assert loss._floor(torch.tensor([0.5, 0.0, 1.0])).tolist() == pytest.approx([0.0, -10.0, 10.0])
    with pytest.raises(ValueError, match="value_loss"):
        make_loss(value_loss="huber")


def test_the_td_target_reads_the_target_critics_not_the_online_ones():
    """Right after construction the target copy equals the online critic, so only moving one of them
    tells which the TD target reads: moving the online critics leaves it, moving the target moves it."""
    loss, batch = make_loss(), make_batch()

    def target() -> torch.Tensor:
        torch.manual_seed(3)  # the same draws of a' ~ pi(.|s') each time
        return loss.terms(batch).target

    before = target()
    with torch.no_grad():
        for p in loss.qvalue_network_params.values(True, True):
            p.add_(0.5)
    torch.testing.assert_close(target(), before, rtol=0, atol=0)
    with torch.no_grad():
        for p in loss.target_qvalue_network_params.values(True, True):
            p.add_(0.5)
    assert not torch.allclose(target(), before)


class _RowCodedDraws:
    """A stand-in for the actor's distribution over the 2B stacked states [s; s']: draw i at stacked row r
    is the action (r, i, 0, ...), so every sampled action says which state and which draw it came from."""

    def __init__(self, rows: int):
        self.rows = rows

    def rsample_and_log_prob(self, shape: tuple[int]) -> tuple[torch.Tensor, torch.Tensor]:
        (draws,) = shape
        drawn = torch.zeros(draws, self.rows, ACT)
        drawn[..., 0] = torch.arange(self.rows, dtype=torch.float32)[None, :]
        drawn[..., 1] = torch.arange(draws, dtype=torch.float32)[:, None]
        return drawn, torch.zeros(draws, self.rows)


def _record_scored_actions(loss) -> list:
    """Make `loss` keep a copy of every action batch its Q-function scores; returns the list it fills."""
    scored = []
    real_q = loss._q

    def recording_q(params, obs, actions):
        scored.append(actions.detach().clone())
        return real_q(params, obs, actions)

    loss._q = recording_q
    return scored


def test_cql_scores_each_states_own_policy_draws_at_that_state():
    """Row b of the CQL term scores, at s_b, the N draws of pi(.|s_b) and then the N draws of pi(.|s'_b)
    (Cal-QL's reference). A reshape that skips the permute would score other states' draws at s_b."""
    loss, batch = make_loss(), make_batch()
    object.__setattr__(loss.actor_network, "distribution", lambda obs: _RowCodedDraws(len(obs)))
    scored = _record_scored_actions(loss)
    loss.terms(batch)
    actions = scored[0]  # (B, 1 + 3N, A): the data action, N uniform, 2N policy draws
    assert actions.shape == (BATCH, 1 + 3 * N, ACT)
    policy = actions[:, 1 + N :]
    for b in range(BATCH):
        assert policy[b, :N, 0].tolist() == [float(b)] * N  # drawn at s_b
        assert policy[b, N:, 0].tolist() == [float(BATCH + b)] * N  # drawn at s'_b
        assert policy[b, :N, 1].tolist() == policy[b, N:, 1].tolist() == [float(i) for i in range(1, N + 1)]


class _RowCodedDensities(_RowCodedDraws):
    """The row-coded draws, each with a log-density of its own: -(0.5 * stacked row + 0.25 * draw)."""

    def rsample_and_log_prob(self, shape: tuple[int]) -> tuple[torch.Tensor, torch.Tensor]:
        drawn, _ = super().rsample_and_log_prob(shape)
        return drawn, _coded_log_density(drawn[..., 0], drawn[..., 1])


def _coded_log_density(row: torch.Tensor, draw: torch.Tensor) -> torch.Tensor:
    return -(0.5 * row + 0.25 * draw)


def test_each_policy_draw_is_scored_with_its_own_log_density():
    """Every policy-drawn action enters the CQL term as Q(s, a) - log pi(a), with the log-density of that very
    action: the log-probabilities are permuted exactly as the actions are. With densities that differ by
    state, any other pairing changes loss_cql."""
    loss, batch = make_loss(), make_batch()
    object.__setattr__(loss.actor_network, "distribution", lambda obs: _RowCodedDensities(len(obs)))
    scored = _record_scored_actions(loss)
    terms = loss.terms(batch)
    policy = scored[0][:, 1 + N :]  # (B, 2N, A): the actions of terms.q_policy, each coded (row, draw)
    own = _coded_log_density(policy[..., 0], policy[..., 1])
    assert terms.policy_log_prob.shape == (BATCH, 2 * N)
    torch.testing.assert_close(terms.policy_log_prob, own, rtol=0, atol=0)
    assert len(set(own[:, 0].tolist())) == BATCH  # the densities differ from state to state
    # loss_cql by hand: cql_weight * sum over critics of mean over states of logsumexp(...) - Q(s, a_data)
    mc = batch["mc_return"].reshape(BATCH)
    expected = 0.0
    for c in range(2):
        gaps = []
        for b in range(BATCH):
            values = [q - ACT * math.log(0.5) for q in terms.q_uniform[c, b].tolist()]
            for j in range(2 * N):
                values.append(max(terms.q_policy[c, b, j].item(), mc[b].item()) - own[b, j].item())
            top = max(values)
            ood = top + math.log(sum(math.exp(v - top) for v in values))
            gaps.append(ood - terms.q_data[c, b].item())
        expected += loss.cql_weight * sum(gaps) / BATCH
    assert loss.cql_loss(batch, terms)[0].item() == pytest.approx(expected, rel=1e-5)
