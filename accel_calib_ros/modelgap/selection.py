"""
One model selection: the set of library effects this session supports.

Candidates are sets of library effects, each fitted jointly (``setfit.SessionFits``) and
compared by one criterion (``criterion``). The search is stepwise over sets:

- **forward**: every effect not yet in the set is added in turn and the set refitted
  jointly; the supported ones compete (``criterion.decide``: BIC, held-out chi² where the
  BIC margin is small, Occam among confounded ties) and the winner joins the set;
- **joint refit**: every member is tested again beside all the others, refitted jointly
  (the searched parameters too); one that is no longer supported is withdrawn, the weakest
  first (a straight drift that a later wander follows, a wander that only took up another
  effect's leftovers);
- **re-decision**: each member's place is contested again by the effects it was
  confounded with when it was named, now beside the rest of the set (the lag named first
  may give way to the simpler temperature_bias once a drift stands beside it).

No probe and no rule between two named effects takes part: the probes say where a
disagreement lives after the selection (``pruning``).
"""

import numpy as np

from .criterion import COLLINEAR, decide, evaluate, rivals, Trial
from .effects import EFFECTS
from .evidence import separation_advice
from .setfit import added


class Selection:
    """What the selection found and why: the set, its steps' rivals, the rejected."""

    def __init__(self):
        self.chosen = []           # names, in the order they joined
        self.candidates = []       # the last round's table (JSON)
        self.vetoed = []           # supported but contradicted, or withdrawn on refit
        self.rivals = {}           # name -> [(rival, correlation, delta_chi2, rival's)]
        self.ties = []             # names whose place a tie decided
        self.rounds = 0


def _row(trial, setfit, evidence, j):
    return {'effect': trial.name, 'F': float(evidence['F'][0, j]),
            'p': float(evidence['p'][0, j]), 'delta_bic': float(evidence['bic'][0, j]),
            'worst_case_mg': float(trial.worst[0]),
            'significant': bool(evidence['significant'][0, j]),
            'large_enough': bool(evidence['large'][0, j]),
            'held_out': bool(evidence['held'][0, j]),
            'supported': bool(evidence['supported'][0, j])}


def _round(fits, chosen, names):
    """Return the trials of adding each of ``names`` to ``chosen``, their set fits, evidence."""
    base = fits.fit(chosen)
    trials, setfits = [], []
    for name in names:
        trial, setfit = fits.trial(chosen, name)
        if trial is not None:
            trials.append(trial)
            setfits.append(setfit)
    evidence = evaluate(np.array([base.chi2]), fits.cv(base)[None, :], trials, fits.n,
                        fits.nu, fits.threshold)
    evidence['drop'] = [base.chi2 - trial.chi2[0] for trial in trials]
    return base, trials, setfits, evidence


def _correlations(fits, base, trials, setfits, evidence):
    """Return the signature correlations (m, m) among the supported trials."""
    m = len(trials)
    corr = np.eye(m)
    live = np.flatnonzero(evidence['supported'][0])
    for a in live:
        for b in live:
            if a < b:
                corr[a, b] = corr[b, a] = fits.correlation(
                    base, (trials[a].name, setfits[a]), (trials[b].name, setfits[b]))
    return corr


def _veto_record(out, trial, evidence, j, step, reason):
    if any(v['effect'] == trial.name for v in out.vetoed):
        return
    out.vetoed.append({'effect': trial.name, 'reason': reason,
                       'worst_case_mg': float(trial.worst[0]), 'F': float(evidence['F'][0, j]),
                       'p': float(evidence['p'][0, j]), 'step': step})


def select(fits, candidates, max_size=4):
    """
    Return the ``Selection`` of effects among ``candidates`` that the session supports.

    :param fits: setfit.SessionFits of the session.
    :param candidates: library names the session can show.
    :param max_size: most effects in the set.
    """
    out = Selection()
    fits.candidates = list(candidates)
    chosen = []
    seen = {frozenset()}
    while len(chosen) < max_size and out.rounds < 3 * max_size:
        out.rounds += 1
        base, trials, setfits, evidence = _round(
            fits, chosen, [n for n in candidates if n not in chosen])
        if not trials:
            break
        out.candidates = [_row(t, s, evidence, j) | {'delta_chi2': float(evidence['drop'][j])}
                          for j, (t, s) in enumerate(zip(trials, setfits))]
        corr = _correlations(fits, base, trials, setfits, evidence)
        winner, tie = decide(evidence, trials, corr)
        w = int(winner[0])
        top = evidence['score'][0, w] if w >= 0 else -np.inf
        for j, trial in enumerate(trials):
            # A contradicted effect is reported when it would have been named without it.
            if (evidence['vetoed'][0, j] and evidence['significant'][0, j]
                    and evidence['large'][0, j] and evidence['score'][0, j] >= top):
                _veto_record(out, trial, evidence, j, len(chosen) + 1, trial.veto[0])
        if w < 0:
            break
        name = trials[w].name
        chosen = added(chosen, name)[0]
        if tie[0]:
            out.ties.append(name)
        out.rivals[name] = [
            (trials[j].name, float(corr[j, w]), float(evidence['drop'][w]),
             float(evidence['drop'][j]))
            for j in rivals(evidence, trials, corr, w)]
        chosen = _refit_jointly(fits, chosen, out)
        chosen = _redecide(fits, chosen, out)
        key = frozenset(chosen)
        if key in seen:
            break
        seen.add(key)
    out.chosen = chosen
    return out


def member_support(fits, chosen, name):
    """
    Return the evidence that ``name`` holds its place in the set ``chosen``, jointly refitted.

    :returns: (supported, evidence dict of (1, 1) arrays, trial).
    """
    full = fits.fit(chosen)
    # Without it, the simpler effects it contains stand in its place (a drift for a wander).
    simpler = [n for n in EFFECTS[name].nests if n in fits.candidates and n not in chosen]
    without = fits.fit([n for n in chosen if n != name] + simpler)
    if full is None or without is None:
        return True, None, None
    k = full.k(name) - sum(without.k(n) for n in simpler)
    trial = Trial(name, EFFECTS[name].variable, k, [full.chi2], full.dof,
                  [fits.size(full, without, name)], [fits.cv(full)],
                  [fits.veto(name, full)])
    evidence = evaluate(np.array([without.chi2]), fits.cv(without)[None, :], [trial], fits.n,
                        fits.nu, fits.threshold)
    evidence['drop'] = [without.chi2 - full.chi2]
    return bool(evidence['supported'][0, 0]), evidence, trial


def _why_not(evidence, trial, others):
    beside = ', '.join(others) or 'the baseline'
    stats = (f'p = {evidence["p"][0, 0]:.2g}, ΔBIC {evidence["bic"][0, 0]:.0f}')
    if trial.veto[0]:
        return trial.veto[0]
    if not evidence['significant'][0, 0]:
        return f'not supported beside {beside} once refitted jointly with it ({stats})'
    if not evidence['large'][0, 0]:
        return (f'beside {beside}, refitted jointly, it is only {trial.worst[0]:.2g} mg, below '
                'the practical threshold')
    return (f'beside {beside}, refitted jointly, it does not lower the chi² of held-out '
            f'windows ({stats})')


def _refit_jointly(fits, chosen, out):
    """Withdraw members that are not supported beside all the others, the weakest first."""
    while len(chosen) > 1:
        weakest = None
        for name in chosen:
            ok, evidence, trial = member_support(fits, chosen, name)
            if ok or evidence is None:
                continue
            p = float(evidence['p'][0, 0])
            if weakest is None or p > weakest[1]:
                weakest = (name, p, evidence, trial)
        if weakest is None:
            break
        name, _, evidence, trial = weakest
        others = [n for n in chosen if n != name]
        _veto_record(out, trial, evidence, 0, chosen.index(name) + 1,
                     _why_not(evidence, trial, others))
        chosen = others
    return chosen


def _redecide(fits, chosen, out):
    """Let each member's confounded rivals contest its place beside the rest of the set."""
    for name in list(chosen):
        contenders = [r[0] for r in out.rivals.get(name, []) if r[0] not in chosen]
        if name not in chosen or not contenders:
            continue
        rest = [n for n in chosen if n != name]
        base, trials, setfits, evidence = _round(fits, rest, [name] + contenders)
        if not trials or trials[0].name != name:
            continue
        corr = _correlations(fits, base, trials, setfits, evidence)
        winner, tie = decide(evidence, trials, corr)
        w = int(winner[0])
        if w <= 0:
            continue
        new = trials[w].name
        # The new member must hold its place and leave the others theirs.
        trial_set = [new if n == name else n for n in chosen]
        if not all(member_support(fits, trial_set, n)[0] for n in trial_set):
            continue
        out.vetoed.append({
            'effect': name, 'worst_case_mg': float(trials[0].worst[0]),
            'F': float(evidence['F'][0, 0]), 'p': float(evidence['p'][0, 0]),
            'step': chosen.index(name) + 1,
            'reason': f'{new} explains as much beside {", ".join(rest) or "the baseline"} '
                      f'with {"fewer or " if trials[w].k[0] <= trials[0].k[0] else ""}as many '
                      f'parameters (ΔBIC {evidence["score"][0, w]:.0f} against '
                      f'{evidence["score"][0, 0]:.0f})'})
        out.rivals[new] = [(name, float(corr[0, w]), float(evidence['drop'][w]),
                            float(evidence['drop'][0]))]
        if tie[0]:
            out.ties.append(new)
        chosen = trial_set
    return chosen


def ambiguity_notes(out, chosen, c):
    """
    Return the notes and the alternatives JSON for the named effects' confounded rivals.

    A rival is an effect that was supported when the named one was chosen, whose signature
    correlates more than ``COLLINEAR`` with it and whose BIC gain was within ``RIVAL_BIC``:
    the note says what to record to separate them.
    """
    notes, alternatives = [], []
    for name in chosen:
        for rival, corr, drop, rival_drop in out.rivals.get(name, []):
            if rival in chosen or corr <= COLLINEAR:
                continue
            advice = separation_advice(name, rival, c)
            notes.append(f'{name} and {rival} are confounded in this session (their '
                         f'signatures correlate {corr:.2f}; chi² drops {drop:.1f} and '
                         f'{rival_drop:.1f}): ' + advice)
            alternatives.append({'effect': rival, 'instead_of': name, 'correlation': corr,
                                 'delta_chi2': rival_drop, 'named_delta_chi2': drop,
                                 'occam': name in out.ties, 'separate_by': advice})
    return notes, alternatives
