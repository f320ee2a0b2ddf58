//! Grounding by relaxed reachability: only the bindings of each schema whose
//! positive preconditions can all hold together in some state reachable from
//! the initial states when deletes are ignored.
//!
//! A fixpoint over atoms, evaluated semi-naively as a Datalog program is: each
//! atom reached is joined, as the newest, with the atoms reached before it
//! through every positive fluent precondition of every schema it matches, and
//! the positive static preconditions join against the problem's static facts.
//! Every complete binding that passes the static checks is an instance, and
//! its add effects (of every outcome) are reached in turn. Negative fluent
//! preconditions are ignored, as the relaxation has it, so the result is an
//! over-approximation of what a search from the initial states can apply.

use std::collections::{HashMap, HashSet};

use super::{Arg, AtomId, CLit, GroundError, GroundLimits, Grounder, Schema};

/// A parameter not bound yet.
const UNBOUND: u32 = u32::MAX;

/// The reachable bindings of one schema, back to back.
pub(super) struct Bindings {
    params: usize,
    count: usize,
    flat: Vec<u32>,
}

impl Bindings {
    fn new(params: usize) -> Bindings {
        Bindings {
            params,
            count: 0,
            flat: Vec::new(),
        }
    }

    fn push(&mut self, binding: &[u32]) {
        self.flat.extend_from_slice(binding);
        self.count += 1;
    }

    /// Each binding once, in lexicographic order: the order in which
    /// grounding every instance builds them.
    pub(super) fn sorted(&self) -> Vec<&[u32]> {
        let n = self.params;
        let mut all: Vec<&[u32]> = (0..self.count)
            .map(|i| &self.flat[i * n..(i + 1) * n])
            .collect();
        all.sort_unstable();
        all.dedup();
        all
    }
}

/// Facts by predicate and by (predicate, argument position, object), to join
/// preconditions against.
#[derive(Default)]
struct Facts {
    keys: Vec<Box<[u32]>>,
    by_predicate: Vec<Vec<u32>>,
    by_argument: HashMap<(u32, u32, u32), Vec<u32>>,
}

impl Facts {
    fn add(&mut self, key: &[u32]) {
        let id = self.keys.len() as u32;
        let predicate = key[0];
        if self.by_predicate.len() <= predicate as usize {
            self.by_predicate
                .resize_with(predicate as usize + 1, Vec::new);
        }
        self.by_predicate[predicate as usize].push(id);
        for (position, &object) in key[1..].iter().enumerate() {
            self.by_argument
                .entry((predicate, position as u32, object))
                .or_default()
                .push(id);
        }
        self.keys.push(key.into());
    }

    /// The facts of `predicate` that `args` may match under `binding`: the
    /// shortest of the lists of those with one bound argument in place.
    fn candidates(&self, predicate: u32, args: &[Arg], binding: &[u32]) -> &[u32] {
        let mut best: &[u32] = self
            .by_predicate
            .get(predicate as usize)
            .map_or(&[], Vec::as_slice);
        for (position, arg) in args.iter().enumerate() {
            let value = match *arg {
                Arg::Obj(o) => o,
                Arg::Param(p) if binding[p] != UNBOUND => binding[p],
                Arg::Param(_) => continue,
            };
            let list = self
                .by_argument
                .get(&(predicate, position as u32, value))
                .map_or(&[][..], Vec::as_slice);
            if list.len() < best.len() {
                best = list;
            }
        }
        best
    }
}

/// Binds `args` to a fact's `objects`, noting in `undo` the parameters it
/// binds; false, with nothing bound, when they disagree (a constant, a bound
/// parameter, or an object not of the parameter's type).
fn unify(
    args: &[Arg],
    objects: &[u32],
    binding: &mut [u32],
    candidates: &[Vec<u32>],
    undo: &mut Vec<usize>,
) -> bool {
    if args.len() != objects.len() {
        return false;
    }
    let mark = undo.len();
    for (arg, &object) in args.iter().zip(objects) {
        let agrees = match *arg {
            Arg::Obj(o) => o == object,
            Arg::Param(p) if binding[p] != UNBOUND => binding[p] == object,
            Arg::Param(p) => {
                let typed = candidates[p].binary_search(&object).is_ok();
                if typed {
                    binding[p] = object;
                    undo.push(p);
                }
                typed
            }
        };
        if !agrees {
            for &p in &undo[mark..] {
                binding[p] = UNBOUND;
            }
            undo.truncate(mark);
            return false;
        }
    }
    true
}

/// The positive atom literals of `schema`'s precondition: those that bind
/// parameters.
fn positive_atoms<'s>(schema: &'s Schema<'_>) -> impl Iterator<Item = (usize, u32, &'s [Arg])> {
    schema
        .pre
        .lits
        .iter()
        .enumerate()
        .filter_map(|(i, lit)| match lit {
            CLit::Atom {
                positive: true,
                predicate,
                args,
            } => Some((i, *predicate, &args[..])),
            _ => None,
        })
}

/// How to join a schema's positive atoms once one of them is bound.
struct JoinPlan {
    /// The other positive atoms, in the order to join them: each time the one
    /// with the most arguments bound so far (so its candidates are looked up
    /// by them), static ones first on ties.
    order: Vec<usize>,
    /// The literals to check once the first atom is bound (`checks[0]`) and
    /// after each atom of `order` (`checks[l + 1]`): equalities and negative
    /// static atoms, as soon as their parameters are all bound, so that
    /// `(not (= ?h1 ?h2))` prunes a join rather than its results.
    checks: Vec<Vec<usize>>,
}

/// The join plan of `schema` from its positive atom `first`.
fn join_plan(schema: &Schema<'_>, first: usize, is_static: &[bool]) -> JoinPlan {
    let n = schema.candidates.len();
    let mut bound = vec![false; n];
    let mark = |bound: &mut Vec<bool>, args: &[Arg]| {
        for arg in args {
            if let Arg::Param(p) = *arg {
                bound[p] = true;
            }
        }
    };
    let mut rest: Vec<(usize, u32, &[Arg])> = Vec::new();
    for (i, predicate, args) in positive_atoms(schema) {
        if i == first {
            mark(&mut bound, args);
        } else {
            rest.push((i, predicate, args));
        }
    }
    let mut order = Vec::with_capacity(rest.len());
    while !rest.is_empty() {
        let score = |&(_, predicate, args): &(usize, u32, &[Arg])| {
            let known = args
                .iter()
                .filter(|a| match **a {
                    Arg::Obj(_) => true,
                    Arg::Param(p) => bound[p],
                })
                .count();
            (known, is_static[predicate as usize])
        };
        let best = (0..rest.len())
            .max_by_key(|&k| (score(&rest[k]), std::cmp::Reverse(k)))
            .unwrap_or(0);
        let (i, _, args) = rest.swap_remove(best);
        mark(&mut bound, args);
        order.push(i);
    }
    // The level at which each parameter is bound: 0 by `first`, l + 1 by `order[l]`.
    let mut level = vec![usize::MAX; n];
    for (l, &i) in std::iter::once(&first).chain(&order).enumerate() {
        if let CLit::Atom { args, .. } = &schema.pre.lits[i] {
            for arg in args {
                if let Arg::Param(p) = *arg {
                    level[p] = level[p].min(l);
                }
            }
        }
    }
    let mut checks = vec![Vec::new(); order.len() + 1];
    for (i, lit) in schema.pre.lits.iter().enumerate() {
        let args: Vec<Arg> = match lit {
            CLit::Eq { a, b, .. } => vec![*a, *b],
            CLit::Atom {
                positive: false,
                predicate,
                args,
            } if is_static[*predicate as usize] => args.clone(),
            CLit::Atom { .. } => continue,
        };
        let at = args
            .iter()
            .map(|a| match *a {
                Arg::Param(p) => level[p],
                Arg::Obj(_) => 0,
            })
            .max()
            .unwrap_or(0);
        // A parameter no positive atom binds is checked when the binding is completed.
        if let Some(checks) = checks.get_mut(at) {
            checks.push(i);
        }
    }
    JoinPlan { order, checks }
}

/// One level of a join: the facts a literal may match, the next to try, and
/// the parameters the current match bound.
struct Frame<'f> {
    facts: &'f [u32],
    cursor: usize,
    undo: Vec<usize>,
}

/// What the fixpoint has found so far.
struct Reach {
    bindings: Vec<Bindings>,
    /// Every atom reached, processed or not.
    reached: HashSet<Box<[u32]>>,
    /// Atoms reached and not yet joined.
    queue: Vec<Box<[u32]>>,
    found: usize,
    bytes: usize,
    limits: GroundLimits,
}

impl Reach {
    /// Reaches the atom `key`: queued unless it was reached before.
    fn reach(&mut self, key: &[u32]) -> Result<(), GroundError> {
        if self.reached.contains(key) {
            return Ok(());
        }
        // The set, the queue and the facts hold it, and the indexes an entry per argument.
        self.bytes = self.bytes.saturating_add(96 + 16 * key.len());
        let key: Box<[u32]> = key.into();
        self.reached.insert(key.clone());
        self.queue.push(key);
        self.check_memory()
    }

    /// Records `binding` of schema `k`, and reaches what it adds.
    fn record(
        &mut self,
        k: usize,
        schema: &Schema<'_>,
        binding: &[u32],
    ) -> Result<(), GroundError> {
        self.found += 1;
        if self.found > self.limits.max_operators {
            return Err(GroundError::TooLarge {
                limit: self.limits.max_operators,
            });
        }
        self.bindings[k].push(binding);
        self.bytes = self.bytes.saturating_add(4 * binding.len() + 8);
        let value = |a: &Arg| match *a {
            Arg::Param(p) => binding[p],
            Arg::Obj(o) => o,
        };
        let outcomes = schema.chances.iter().flatten().flat_map(|(_, e)| e);
        let mut key = Vec::new();
        for (is_add, predicate, args) in schema.effects.iter().chain(outcomes) {
            if *is_add {
                key.clear();
                key.push(*predicate);
                key.extend(args.iter().map(value));
                self.reach(&key)?;
            }
        }
        self.check_memory()
    }

    fn check_memory(&self) -> Result<(), GroundError> {
        if self.bytes > self.limits.max_bytes {
            return Err(GroundError::TooMuchMemory {
                limit_mib: self.limits.max_bytes / (1024 * 1024),
            });
        }
        Ok(())
    }
}

impl Grounder<'_> {
    /// The bindings of each of `schemas` that relaxed reachability reaches
    /// from the atoms of `start` (every initial world's), each that passes
    /// the schema's static checks, in no particular order.
    pub(super) fn reachable_bindings(
        &mut self,
        schemas: &[(usize, Schema<'_>)],
        start: &[AtomId],
    ) -> Result<Vec<Bindings>, GroundError> {
        let is_static = self.task.static_predicate.clone();
        let mut facts = Facts::default();
        for key in &self.task.statics {
            facts.add(key);
        }
        // For each fluent predicate, the positive preconditions it matches,
        // as (schema, literal), with the order to join the rest in.
        let mut triggers: HashMap<u32, Vec<(usize, usize, JoinPlan)>> = HashMap::new();
        let mut always = Vec::new();
        for (k, (_, schema)) in schemas.iter().enumerate() {
            let mut fluent = false;
            for (i, predicate, _) in positive_atoms(schema) {
                if !is_static[predicate as usize] {
                    fluent = true;
                    let plan = join_plan(schema, i, &is_static);
                    triggers.entry(predicate).or_default().push((k, i, plan));
                }
            }
            if !fluent {
                always.push(k);
            }
        }
        let mut reach = Reach {
            bindings: schemas
                .iter()
                .map(|(_, s)| Bindings::new(s.candidates.len()))
                .collect(),
            reached: HashSet::new(),
            queue: Vec::new(),
            found: 0,
            bytes: 0,
            limits: self.limits,
        };
        for &atom in start {
            let key = self.task.atoms[atom.index()].clone();
            reach.reach(&key)?;
        }
        // Schemas without a positive fluent precondition apply from the start.
        for k in always {
            let schema = &schemas[k].1;
            let candidates: Vec<&[u32]> = schema.candidates.iter().map(Vec::as_slice).collect();
            self.instantiate(schema, &candidates, &mut |_, binding| {
                reach.record(k, schema, binding)
            })?;
        }
        while let Some(key) = reach.queue.pop() {
            facts.add(&key);
            let Some(matches) = triggers.get(&key[0]) else {
                continue;
            };
            for (k, i, plan) in matches {
                self.join(&schemas[*k].1, *k, *i, plan, &key, &facts, &mut reach)?;
            }
        }
        Ok(reach.bindings)
    }

    /// Joins the newest atom `key`, as literal `first` of schema `k`, with the
    /// facts so far through the schema's other positive preconditions as
    /// `plan` says, and records each complete binding.
    #[allow(clippy::too_many_arguments)]
    fn join(
        &mut self,
        schema: &Schema<'_>,
        k: usize,
        first: usize,
        plan: &JoinPlan,
        key: &[u32],
        facts: &Facts,
        reach: &mut Reach,
    ) -> Result<(), GroundError> {
        let lits = &schema.pre.lits;
        let args_of = |i: usize| match &lits[i] {
            CLit::Atom { args, .. } => &args[..],
            CLit::Eq { .. } => &[],
        };
        let predicate_of = |i: usize| match &lits[i] {
            CLit::Atom { predicate, .. } => *predicate,
            CLit::Eq { .. } => 0,
        };
        let mut binding = vec![UNBOUND; schema.candidates.len()];
        let mut undo = Vec::new();
        if !unify(
            args_of(first),
            &key[1..],
            &mut binding,
            &schema.candidates,
            &mut undo,
        ) || !plan.checks[0]
            .iter()
            .all(|&i| self.holds(&lits[i], &binding))
        {
            return Ok(());
        }
        let order = &plan.order;
        let mut stack: Vec<Frame<'_>> = Vec::with_capacity(order.len());
        loop {
            if stack.len() == order.len() {
                self.complete(schema, k, first, key, &binding, reach)?;
            } else {
                let i = order[stack.len()];
                stack.push(Frame {
                    facts: facts.candidates(predicate_of(i), args_of(i), &binding),
                    cursor: 0,
                    undo: Vec::new(),
                });
            }
            // The next match at the deepest level that has one.
            let matched = loop {
                let Some(level) = stack.len().checked_sub(1) else {
                    break false;
                };
                let args = args_of(order[level]);
                let top = &mut stack[level];
                for &p in &top.undo {
                    binding[p] = UNBOUND;
                }
                top.undo.clear();
                let mut hit = false;
                while top.cursor < top.facts.len() {
                    let fact = top.facts[top.cursor] as usize;
                    top.cursor += 1;
                    self.tick()?;
                    let objects = &facts.keys[fact][1..];
                    if !unify(
                        args,
                        objects,
                        &mut binding,
                        &schema.candidates,
                        &mut top.undo,
                    ) {
                        continue;
                    }
                    if plan.checks[level + 1]
                        .iter()
                        .all(|&i| self.holds(&lits[i], &binding))
                    {
                        hit = true;
                        break;
                    }
                    for &p in &top.undo {
                        binding[p] = UNBOUND;
                    }
                    top.undo.clear();
                }
                if hit {
                    break true;
                }
                stack.pop();
            };
            if !matched {
                return Ok(());
            }
        }
    }

    /// Completes a join's `binding` of schema `k` over the parameters no
    /// positive precondition binds, and records each that passes the static
    /// checks. A binding whose newest atom `key` an earlier literal than
    /// `first` grounds too is left to that literal, so each is found once.
    fn complete(
        &mut self,
        schema: &Schema<'_>,
        k: usize,
        first: usize,
        key: &[u32],
        binding: &[u32],
        reach: &mut Reach,
    ) -> Result<(), GroundError> {
        let grounds_key = |i: usize| match &schema.pre.lits[i] {
            CLit::Atom {
                positive: true,
                predicate,
                args,
            } if !self.task.static_predicate[*predicate as usize] => {
                key[0] == *predicate
                    && args.len() + 1 == key.len()
                    && args.iter().zip(&key[1..]).all(|(a, &o)| match *a {
                        Arg::Obj(c) => c == o,
                        Arg::Param(p) => binding[p] == o,
                    })
            }
            _ => false,
        };
        if (0..first).any(grounds_key) {
            return Ok(());
        }
        let candidates: Vec<&[u32]> = binding
            .iter()
            .zip(&schema.candidates)
            .map(|(value, typed)| {
                if *value == UNBOUND {
                    typed.as_slice()
                } else {
                    std::slice::from_ref(value)
                }
            })
            .collect();
        self.instantiate(schema, &candidates, &mut |_, found| {
            reach.record(k, schema, found)
        })
    }
}
