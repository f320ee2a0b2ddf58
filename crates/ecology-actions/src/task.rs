//! Grounding: typed action schemas over a problem's objects become operators
//! on STRIPS states, which are bitsets of ground atoms.
//!
//! Predicates that no action changes are *static*: their literals are decided
//! while grounding (an operator whose static precondition fails is never
//! built), and they are left out of the state. Everything else is a fluent,
//! interned as an [`AtomId`] on first use. An action is grounded one variant
//! at a time ([`ecology_domain::Action::variants`]: a disjunct of its
//! precondition, each `when` condition holding or failing), so one instance
//! may be several operators; `reach` grounds only what relaxed reachability
//! reaches.

use std::collections::{HashMap, HashSet};
use std::fmt;

use ecology_domain::{Action, Call, Domain, Effect, Literal, Name, NumExpr, Problem, Term};

mod reach;

/// A ground fluent atom such as `(at astrid entrance)`, by index.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct AtomId(pub u32);

/// A ground action instance (an operator) of a [`Task`], by index.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct OpId(pub u32);

impl AtomId {
    fn index(self) -> usize {
        self.0 as usize
    }
}

impl OpId {
    /// The index into [`Task::operators`].
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// A world state: the set of fluent atoms that hold (closed world).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct State {
    pub(crate) words: Vec<u64>,
}

impl State {
    /// Applies an effect: deletes first, then adds, so an atom both deleted and added holds.
    pub(crate) fn change(&mut self, add: &[AtomId], del: &[AtomId]) {
        for &a in del {
            self.clear(a);
        }
        for &a in add {
            self.set(a);
        }
    }

    pub(crate) fn empty(atoms: usize) -> State {
        State {
            words: vec![0; atoms.div_ceil(64).max(1)],
        }
    }

    pub(crate) fn from_words(words: &[u64]) -> State {
        State {
            words: words.to_vec(),
        }
    }

    /// Whether `atom` holds.
    pub fn holds(&self, atom: AtomId) -> bool {
        self.words
            .get(atom.index() / 64)
            .is_some_and(|w| w >> (atom.index() % 64) & 1 == 1)
    }

    pub(crate) fn set(&mut self, atom: AtomId) {
        self.words[atom.index() / 64] |= 1 << (atom.index() % 64);
    }

    pub(crate) fn clear(&mut self, atom: AtomId) {
        self.words[atom.index() / 64] &= !(1 << (atom.index() % 64));
    }

    /// The atoms that hold, in increasing order.
    pub fn atoms(&self) -> impl Iterator<Item = AtomId> + '_ {
        self.words.iter().enumerate().flat_map(|(i, &word)| {
            let mut w = word;
            std::iter::from_fn(move || {
                if w == 0 {
                    return None;
                }
                let bit = w.trailing_zeros();
                w &= w - 1;
                Some(AtomId(i as u32 * 64 + bit))
            })
        })
    }
}

/// A ground action: an action schema with its parameters bound to objects.
#[derive(Debug, Clone, PartialEq)]
pub struct Operator {
    /// The action schema's name.
    pub action: Name,
    /// The objects bound to its parameters, in order.
    pub args: Vec<Name>,
    /// Fluent atoms that must hold.
    pub pre: Vec<AtomId>,
    /// Fluent atoms that must not hold.
    pub pre_neg: Vec<AtomId>,
    /// Atoms it makes true.
    pub add: Vec<AtomId>,
    /// Atoms it makes false (none of them also in `add`: adding wins).
    pub del: Vec<AtomId>,
    /// What it costs: 1 without `:action-costs`, else its `(increase (total-cost) ...)`.
    pub cost: u64,
    /// Its ground `:configure` goal, if the schema has one.
    pub configure: Option<Call>,
    /// Its probabilistic outcomes, each with its complete add and delete
    /// lists; empty for a deterministic operator, whose one outcome is
    /// `add`/`del`. When not empty, `add` and `del` hold what every outcome
    /// does, and only the conditional planner applies the operator.
    pub outcomes: Vec<Chance>,
    /// The atoms whose truth the operator reveals after its effects (`:observe`).
    pub observe: Vec<AtomId>,
}

/// One outcome of a probabilistic operator.
#[derive(Debug, Clone, PartialEq)]
pub struct Chance {
    /// Its probability, in `(0, 1]`; an operator's outcomes sum to 1.
    pub probability: f64,
    /// Atoms it makes true.
    pub add: Vec<AtomId>,
    /// Atoms it makes false (none of them also in `add`).
    pub del: Vec<AtomId>,
}

impl Operator {
    /// Each outcome as `(probability, add, del)`: the one outcome of a
    /// deterministic operator, with probability 1.
    pub fn each_outcome(&self) -> impl Iterator<Item = (f64, &[AtomId], &[AtomId])> {
        let deterministic = self
            .outcomes
            .is_empty()
            .then_some((1.0, &self.add[..], &self.del[..]));
        deterministic.into_iter().chain(
            self.outcomes
                .iter()
                .map(|o| (o.probability, &o.add[..], &o.del[..])),
        )
    }
}

/// Outcomes one operator may have at most (the product of its
/// `probabilistic` forms' outcomes).
pub const MAX_OUTCOMES: usize = 4096;

/// Possible initial worlds a problem may have at most (the product of its
/// uncertain facts' outcomes).
pub const MAX_WORLDS: usize = 65_536;

impl fmt::Display for Operator {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "({}", self.action)?;
        for arg in &self.args {
            write!(f, " {arg}")?;
        }
        f.write_str(")")
    }
}

/// Grounding failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GroundError {
    /// A schema mentions a variable that is not one of its parameters
    /// (validated domains never do).
    #[error("action `{action}` uses `?{var}`, which is not one of its parameters")]
    UnboundVariable {
        /// The action schema.
        action: String,
        /// The variable, without `?`.
        var: String,
    },
    /// The goal has a variable.
    #[error("the goal must be ground, but it mentions `?{0}`")]
    VariableInGoal(String),
    /// Grounding would build more operators than the limit.
    #[error("grounding builds more than {limit} operators; the problem is too large")]
    TooLarge {
        /// The limit that was reached.
        limit: usize,
    },
    /// Grounding would hold more memory than its limit.
    #[error("grounding needs more than {limit_mib} MiB; the problem is too large")]
    TooMuchMemory {
        /// The limit that was reached, in MiB.
        limit_mib: usize,
    },
    /// An action has more outcomes than [`MAX_OUTCOMES`], or the initial
    /// state more possible worlds than [`MAX_WORLDS`].
    #[error("{what} has more than {limit} possible outcomes; the problem is too large")]
    TooUncertain {
        /// The action schema, or `the initial state`.
        what: String,
        /// The limit that was reached.
        limit: usize,
    },
    /// Grounding took longer than its time limit.
    #[error("grounding took longer than the time limit of {limit:?}")]
    OutOfTime {
        /// The limit that was reached.
        limit: std::time::Duration,
    },
}

/// Which action instances grounding builds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Instances {
    /// Every binding whose static preconditions hold: the task serves a
    /// search from any state, as replanning needs.
    #[default]
    All,
    /// Only the bindings whose positive preconditions can all hold in a state
    /// reachable from the problem's initial states when deletes are ignored
    /// (relaxed reachability, as Fast Downward's translator grounds): no
    /// search from those states needs the others, and problems whose schemas
    /// have many parameters ground in a fraction of the time and memory. A
    /// search from any other state may lack operators it needs.
    Reachable,
}

/// Limits on grounding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GroundLimits {
    /// Operators built at most.
    pub max_operators: usize,
    /// Time at most, as the caller's clock measures it.
    pub max_time: Option<std::time::Duration>,
    /// Memory the operators may hold at most, in bytes (estimated as they are built).
    pub max_bytes: usize,
    /// Which instances to build.
    pub instances: Instances,
}

impl Default for GroundLimits {
    fn default() -> Self {
        GroundLimits {
            max_operators: MAX_OPERATORS,
            max_time: None,
            max_bytes: 512 * 1024 * 1024,
            instances: Instances::All,
        }
    }
}

/// How many candidate bindings grounding tries between two looks at the clock.
const CLOCK_EVERY: u32 = 4096;

/// A ground action instance could not be found from its name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum InstanceError {
    /// No action schema has that name.
    #[error("unknown action `{0}`")]
    UnknownAction(String),
    /// Wrong number of arguments.
    #[error("wrong arity: `{action}` takes {expected} arguments, given {given}")]
    Arity {
        /// The action schema.
        action: String,
        /// Its parameter count.
        expected: usize,
        /// Arguments given.
        given: usize,
    },
    /// An argument is a variable.
    #[error("an action instance is ground, but `?{0}` is a variable")]
    NotGround(String),
    /// An argument names no object or constant.
    #[error("unknown object `{0}`")]
    UnknownObject(String),
}

/// A state could not be built from atoms.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StateError {
    /// The atom is of a static predicate and disagrees with the problem's
    /// `:init`; the task must be grounded again from a new problem.
    #[error("`{0}` is static (no action changes it) and differs from the problem's init")]
    StaticChanged(String),
}

/// The most operators grounding builds before giving up.
pub const MAX_OPERATORS: usize = 4_000_000;

/// Ends the list of an instance's variants ([`Task::variants`]).
const NO_VARIANT: u32 = u32::MAX;

/// A ground planning task: fluent atoms, operators, an initial state, a goal.
#[derive(Debug, Clone)]
pub struct Task {
    predicates: Vec<Name>,
    objects: Vec<Name>,
    object_ids: HashMap<Name, u32>,
    /// `[predicate, args...]` for each atom.
    atoms: Vec<Vec<u32>>,
    atom_ids: HashMap<Vec<u32>, AtomId>,
    static_predicate: Vec<bool>,
    statics: HashSet<Vec<u32>>,
    operators: Vec<Operator>,
    initial: State,
    /// The possible initial worlds with their probabilities (summing to 1):
    /// `[(1, initial)]` unless the problem has uncertain facts.
    initial_belief: Vec<(f64, State)>,
    goal: Vec<AtomId>,
    goal_neg: Vec<AtomId>,
    goal_false: Vec<String>,
    arities: HashMap<Name, usize>,
    /// For each atom, the operators whose first precondition it is.
    by_first_pre: Vec<Vec<OpId>>,
    /// Operators without positive preconditions.
    no_pre: Vec<OpId>,
    /// For each operator, the first operator of its action instance
    /// ([`Task::variants`]).
    first_variant: Vec<u32>,
    /// For each operator, the next operator of its action instance
    /// ([`NO_VARIANT`] after the last).
    next_variant: Vec<u32>,
    action_costs: bool,
}

impl Task {
    /// Every operator, indexed by [`OpId`].
    pub fn operators(&self) -> &[Operator] {
        &self.operators
    }

    /// The operator `op`.
    pub fn operator(&self, op: OpId) -> &Operator {
        &self.operators[op.index()]
    }

    /// What the operators `ops` cost together.
    pub fn cost_of(&self, ops: &[OpId]) -> u64 {
        ops.iter()
            .map(|&op| self.operator(op).cost)
            .fold(0, u64::saturating_add)
    }

    /// How many fluent atoms the state has.
    pub fn atom_count(&self) -> usize {
        self.atoms.len()
    }

    /// The problem's initial state.
    pub fn initial(&self) -> &State {
        &self.initial
    }

    /// The possible initial worlds and their probabilities: the problem's
    /// certain `:init` facts plus one outcome of each uncertain fact.
    /// [`Task::initial`] holds the certain facts alone.
    pub fn initial_belief(&self) -> &[(f64, State)] {
        &self.initial_belief
    }

    /// Whether the task needs the conditional planner: an operator with
    /// probabilistic outcomes or observations, or an uncertain initial state.
    pub fn is_uncertain(&self) -> bool {
        self.initial_belief.len() > 1
            || self
                .operators
                .iter()
                .any(|o| !o.outcomes.is_empty() || !o.observe.is_empty())
    }

    /// The all-outcomes determinization: every outcome of every operator
    /// becomes a deterministic operator of its own, and the initial state is
    /// the certain facts. Returns it with, for each of its operators, the
    /// operator of `self` it comes from. Any plan that reaches the goal in
    /// some outcome sequence is a plan of it, so its admissible heuristics
    /// bound the cost of reaching the goal in `self` from below.
    pub fn determinized(&self) -> (Task, Vec<OpId>) {
        let mut task = self.clone();
        let mut origin = Vec::new();
        task.operators.clear();
        for (i, o) in self.operators.iter().enumerate() {
            for (_, add, del) in o.each_outcome() {
                task.operators.push(Operator {
                    add: add.to_vec(),
                    del: del.to_vec(),
                    outcomes: Vec::new(),
                    observe: Vec::new(),
                    ..o.clone()
                });
                origin.push(OpId(i as u32));
            }
        }
        task.initial_belief = vec![(1.0, task.initial.clone())];
        task.index_operators();
        (task, origin)
    }

    /// Indexes the operators by first precondition, each its own instance
    /// (until [`Task::index_variants`]).
    fn index_operators(&mut self) {
        self.by_first_pre = vec![Vec::new(); self.atoms.len()];
        self.no_pre.clear();
        for (i, o) in self.operators.iter().enumerate() {
            match o.pre.first() {
                Some(a) => self.by_first_pre[a.index()].push(OpId(i as u32)),
                None => self.no_pre.push(OpId(i as u32)),
            }
        }
        self.first_variant = (0..self.operators.len() as u32).collect();
        self.next_variant = vec![NO_VARIANT; self.operators.len()];
    }

    /// Links the operators of one instance of the `varied` actions (those
    /// with several variants); the others' operators are each an instance.
    fn index_variants(&mut self, varied: &HashSet<&str>) {
        if varied.is_empty() {
            return;
        }
        let mut last: HashMap<(&str, &[Name]), u32> = HashMap::new();
        for (i, o) in self.operators.iter().enumerate() {
            if !varied.contains(&*o.action) {
                continue;
            }
            let i = i as u32;
            match last.insert((&o.action, &o.args), i) {
                Some(before) => {
                    self.next_variant[before as usize] = i;
                    self.first_variant[i as usize] = self.first_variant[before as usize];
                }
                None => self.first_variant[i as usize] = i,
            }
        }
    }

    /// The operators of `op`'s action instance, `op` among them, in
    /// increasing order: one per variant of the action that grounding kept
    /// (a disjunct of its precondition, each of its `when` conditions
    /// holding or failing), so `op` alone for most actions. Where several
    /// apply they do the same, since each `when` holds or fails alike in
    /// them; the first stands for the instance in conditional plans.
    pub fn variants(&self, op: OpId) -> impl Iterator<Item = OpId> + '_ {
        let mut next = self.first_variant[op.index()];
        std::iter::from_fn(move || {
            let here = next;
            (here != NO_VARIANT).then(|| {
                next = self.next_variant[here as usize];
                OpId(here)
            })
        })
    }

    /// The operator of `op`'s action instance that applies in `state` (the
    /// first, where several do), if any: the instance applies where one of
    /// its variants does, and does what that variant does.
    pub fn variant_in(&self, state: &State, op: OpId) -> Option<OpId> {
        self.variants(op).find(|&v| self.applicable(state, v))
    }

    /// Atoms the goal requires to hold.
    pub fn goal(&self) -> &[AtomId] {
        &self.goal
    }

    /// Atoms the goal requires not to hold.
    pub fn goal_neg(&self) -> &[AtomId] {
        &self.goal_neg
    }

    /// Goal literals over static predicates or equality that are false, so no
    /// plan exists (empty for a goal that might be reachable).
    pub fn goal_false(&self) -> &[String] {
        &self.goal_false
    }

    /// Whether costs come from `(increase (total-cost) ...)` (`:action-costs`)
    /// rather than one per action.
    pub fn has_action_costs(&self) -> bool {
        self.action_costs
    }

    /// Whether the goal holds in `state`.
    pub fn is_goal(&self, state: &State) -> bool {
        self.goal_false.is_empty()
            && self.goal.iter().all(|&a| state.holds(a))
            && !self.goal_neg.iter().any(|&a| state.holds(a))
    }

    /// Whether `op` can be applied in `state`.
    pub fn applicable(&self, state: &State, op: OpId) -> bool {
        let o = &self.operators[op.index()];
        o.pre.iter().all(|&a| state.holds(a)) && !o.pre_neg.iter().any(|&a| state.holds(a))
    }

    /// The state after applying `op` (whose preconditions are not checked).
    pub fn apply(&self, state: &State, op: OpId) -> State {
        let mut next = state.clone();
        self.apply_in_place(&mut next, op);
        next
    }

    pub(crate) fn apply_in_place(&self, state: &mut State, op: OpId) {
        let o = &self.operators[op.index()];
        state.change(&o.add, &o.del);
    }

    /// Calls `f` with every operator applicable in `state`.
    pub fn for_each_applicable(&self, state: &State, f: impl FnMut(OpId)) {
        self.for_each_applicable_counted(state, f);
    }

    /// Like [`Task::for_each_applicable`]; returns how many operators it
    /// looked at, applicable or not: the work of finding the successors.
    pub(crate) fn for_each_applicable_counted(
        &self,
        state: &State,
        mut f: impl FnMut(OpId),
    ) -> u64 {
        let mut looked = self.no_pre.len() as u64;
        let check = |op: OpId, f: &mut dyn FnMut(OpId)| {
            let o = &self.operators[op.index()];
            if o.pre[1..].iter().all(|&a| state.holds(a))
                && !o.pre_neg.iter().any(|&a| state.holds(a))
            {
                f(op);
            }
        };
        for atom in state.atoms() {
            let ops = &self.by_first_pre[atom.index()];
            looked += ops.len() as u64;
            for &op in ops {
                check(op, &mut f);
            }
        }
        for &op in &self.no_pre {
            let o = &self.operators[op.index()];
            if !o.pre_neg.iter().any(|&a| state.holds(a)) {
                f(op);
            }
        }
        looked
    }

    /// Operators no search from `initial` needs: the excluded ones, those
    /// whose positive preconditions cannot all hold in any state reachable
    /// from `initial` (not even when deletes are ignored), and those that
    /// change no state they apply to. Searching without them finds the same
    /// plans, with fewer successors to test and a smaller relaxation.
    pub(crate) fn useless_operators(&self, initial: &State, excluded: &[bool]) -> Vec<bool> {
        let fired = self.relaxed_reachable(initial, excluded);
        self.operators
            .iter()
            .enumerate()
            .map(|(i, o)| {
                let no_change = o.add.iter().all(|a| o.pre.contains(a))
                    && o.del.iter().all(|a| o.pre_neg.contains(a));
                !fired[i] || no_change
            })
            .collect()
    }

    /// For each operator, whether its positive preconditions can all hold in
    /// a state reachable from `initial` without the `excluded` operators when
    /// deletes are ignored.
    pub(crate) fn relaxed_reachable(&self, initial: &State, excluded: &[bool]) -> Vec<bool> {
        let n = self.operators.len();
        let is_excluded = |i: usize| excluded.get(i).copied().unwrap_or(false);
        // Operators by each positive precondition, as flat lists.
        let mut start = vec![0u32; self.atoms.len() + 1];
        for o in &self.operators {
            for a in &o.pre {
                start[a.index() + 1] += 1;
            }
        }
        for i in 0..self.atoms.len() {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut consumers = vec![0u32; start[self.atoms.len()] as usize];
        for (i, o) in self.operators.iter().enumerate() {
            for a in &o.pre {
                consumers[fill[a.index()] as usize] = i as u32;
                fill[a.index()] += 1;
            }
        }
        let mut reached = self.fit(initial);
        let mut stack: Vec<AtomId> = reached.atoms().collect();
        let mut unsatisfied: Vec<u32> = self.operators.iter().map(|o| o.pre.len() as u32).collect();
        let mut fired = vec![false; n];
        let mut fire = |i: usize, reached: &mut State, stack: &mut Vec<AtomId>| {
            fired[i] = true;
            for &a in &self.operators[i].add {
                if !reached.holds(a) {
                    reached.set(a);
                    stack.push(a);
                }
            }
        };
        for (i, o) in self.operators.iter().enumerate() {
            if o.pre.is_empty() && !is_excluded(i) {
                fire(i, &mut reached, &mut stack);
            }
        }
        while let Some(a) = stack.pop() {
            for &i in &consumers[start[a.index()] as usize..start[a.index() + 1] as usize] {
                let i = i as usize;
                unsatisfied[i] -= 1;
                if unsatisfied[i] == 0 && !is_excluded(i) {
                    fire(i, &mut reached, &mut stack);
                }
            }
        }
        fired
    }

    /// `state` cut to this task's atoms, so that a state from elsewhere (for
    /// example another task) cannot index out of bounds.
    pub(crate) fn fit(&self, state: &State) -> State {
        let mut fitted = State::empty(self.atoms.len());
        for (slot, &word) in fitted.words.iter_mut().zip(&state.words) {
            *slot = word;
        }
        let bits = self.atoms.len() % 64;
        if bits != 0
            && let Some(last) = fitted.words.last_mut()
        {
            *last &= (1u64 << bits) - 1;
        }
        if self.atoms.is_empty() {
            fitted.words.fill(0);
        }
        fitted
    }

    /// The predicate of an atom, as an index among the task's predicates.
    pub(crate) fn predicate_of(&self, atom: AtomId) -> u32 {
        self.atoms[atom.index()][0]
    }

    /// The atom written `(predicate args...)`, for people.
    pub fn atom_name(&self, atom: AtomId) -> String {
        let key = &self.atoms[atom.index()];
        let mut out = format!("({}", self.predicates[key[0] as usize]);
        for &o in &key[1..] {
            out.push(' ');
            out.push_str(&self.objects[o as usize]);
        }
        out.push(')');
        out
    }

    /// The fluent atom `(predicate args...)`, if grounding built it.
    pub fn atom(&self, predicate: &str, args: &[&str]) -> Option<AtomId> {
        let key = self.key(predicate, args)?;
        self.atom_ids.get(&key).copied()
    }

    fn key(&self, predicate: &str, args: &[&str]) -> Option<Vec<u32>> {
        let p = self.predicates.iter().position(|q| &**q == predicate)?;
        let mut key = vec![p as u32];
        for a in args {
            key.push(*self.object_ids.get(*a)?);
        }
        Some(key)
    }

    /// A state from the ground atoms that hold (closed world), for replanning
    /// from where the world is now. Fluent atoms no operator or goal mentions
    /// cannot matter and are ignored; static atoms must agree with the
    /// problem's `:init`.
    pub fn state_from<'s>(
        &self,
        atoms: impl IntoIterator<Item = (&'s str, Vec<&'s str>)>,
    ) -> Result<State, StateError> {
        let mut state = State::empty(self.atoms.len());
        let mut statics_seen = HashSet::new();
        for (predicate, args) in atoms {
            let key = self.key(predicate, &args);
            let is_static = key
                .as_ref()
                .is_some_and(|k| self.static_predicate[k[0] as usize]);
            if is_static {
                let k = key.unwrap_or_default();
                if !self.statics.contains(&k) {
                    return Err(StateError::StaticChanged(format!(
                        "({predicate} {})",
                        args.join(" ")
                    )));
                }
                statics_seen.insert(k);
            } else if let Some(&id) = key.as_ref().and_then(|k| self.atom_ids.get(k)) {
                state.set(id);
            }
        }
        if let Some(missing) = self.statics.iter().find(|k| !statics_seen.contains(*k)) {
            let mut text = format!("({}", self.predicates[missing[0] as usize]);
            for &o in &missing[1..] {
                text.push(' ');
                text.push_str(&self.objects[o as usize]);
            }
            text.push(')');
            return Err(StateError::StaticChanged(text));
        }
        Ok(state)
    }

    /// The ground operator written `(action args...)`: `Ok(None)` when the
    /// instance is well formed but can never apply (grounding pruned it).
    /// An action with a disjunctive precondition or conditional effects may
    /// have several operators for one instance; this is the first,
    /// [`Task::find_operators`] all.
    pub fn find_operator(&self, call: &Call) -> Result<Option<OpId>, InstanceError> {
        Ok(self.find_operators(call)?.first().copied())
    }

    /// Every operator of the instance written `(action args...)`: one per
    /// variant of the action that can hold (a disjunct of its precondition,
    /// with each `when` condition holding or failing; one for a conjunctive
    /// precondition without `when`), none when grounding pruned it. Excluding
    /// an instance excludes them all.
    pub fn find_operators(&self, call: &Call) -> Result<Vec<OpId>, InstanceError> {
        let Some(&arity) = self.arities.get(&call.name) else {
            return Err(InstanceError::UnknownAction(call.name.to_string()));
        };
        if arity != call.args.len() {
            return Err(InstanceError::Arity {
                action: call.name.to_string(),
                expected: arity,
                given: call.args.len(),
            });
        }
        let mut args = Vec::new();
        for t in &call.args {
            match t {
                Term::Var(v) => return Err(InstanceError::NotGround(v.to_string())),
                Term::Const(c) if self.object_ids.contains_key(c) => args.push(c.clone()),
                Term::Const(c) => return Err(InstanceError::UnknownObject(c.to_string())),
            }
        }
        Ok(self
            .operators
            .iter()
            .enumerate()
            .filter(|(_, o)| o.action == call.name && o.args == args)
            .map(|(i, _)| OpId(i as u32))
            .collect())
    }
}

/// An argument of a compiled literal: a parameter's position or an object.
#[derive(Debug, Clone, Copy)]
enum Arg {
    Param(usize),
    Obj(u32),
}

/// A literal of a schema with names resolved.
#[derive(Debug, Clone)]
enum CLit {
    Atom {
        positive: bool,
        predicate: u32,
        args: Vec<Arg>,
    },
    Eq {
        positive: bool,
        a: Arg,
        b: Arg,
    },
}

/// An effect of a schema with names resolved: `(is_add, predicate, args)`.
type CEffect = (bool, u32, Vec<Arg>);

/// An operator of an action with several variants, as grounding built it:
/// the variant's `when` effects, the binding, and the positive and negative
/// preconditions.
type Instance = (Vec<usize>, Vec<u32>, Vec<AtomId>, Vec<AtomId>);

/// A cost term of a schema with names resolved: `(function, amount, args)`,
/// the amount when there is no function.
type CCost = (Option<Name>, u64, Vec<Arg>);

/// A precondition compiled for grounding: its literals, which of them are
/// fluent, and at which depth of the binding each of the others (static and
/// equality literals) is checked: as soon as its last parameter is bound.
struct Precondition {
    lits: Vec<CLit>,
    dynamic: Vec<usize>,
    checks: Vec<Vec<usize>>,
}

/// A schema compiled for grounding: one variant of an action (see
/// [`Action::variants`]) with its precondition, its effects as `(is_add,
/// predicate, args)`, its cost terms as `(function, amount, args)`, and its
/// `:configure` goal.
struct Schema<'a> {
    action: &'a Action,
    pre: Precondition,
    effects: Vec<CEffect>,
    costs: Vec<CCost>,
    configure: Option<(&'a Call, Vec<Arg>)>,
    /// Each `probabilistic` form's outcomes (the rest, "nothing happens", included).
    chances: Vec<Vec<(f64, Vec<CEffect>)>>,
    observe: Vec<(u32, Vec<Arg>)>,
    /// The objects each parameter may take (of its type), in increasing order.
    candidates: Vec<Vec<u32>>,
    /// When the action has other variants (disjuncts of its precondition,
    /// ways its `when` conditions hold or fail), the `when` effects of this
    /// one: operators of variants alike in these may repeat this one's.
    variants: Option<Vec<usize>>,
}

struct Grounder<'a> {
    problem: &'a Problem,
    task: Task,
    limits: GroundLimits,
    clock: &'a dyn crate::Clock,
    /// Bindings tried since the clock was last read.
    ticks: u32,
    /// Estimated bytes the operators built so far hold.
    bytes: usize,
    /// Each object's declared type.
    object_types: Vec<Name>,
    parents: HashMap<Name, Name>,
    fluent_values: HashMap<(Name, Vec<u32>), u64>,
    /// The operators built of the action being grounded, when it has several
    /// variants.
    seen_instances: HashSet<Instance>,
}

/// Whether actions cost the sum of their `increase` effects (else 1 each): when the domain says
/// `:action-costs`, or the problem minimizes `total-cost` (as other planners read IPC domains
/// that declare only the metric). The grounder and the validator price actions alike.
pub(crate) fn priced_by_effects(domain: &Domain, problem: &Problem) -> bool {
    domain.requires("action-costs")
        || problem.metric == Some(ecology_domain::Metric::MinimizeTotalCost)
}

/// Grounds `domain`'s actions over `problem`'s objects and the domain's
/// constants.
///
/// The problem is assumed to be checked against the domain
/// ([`ecology_domain::check_problem`]); names it does not declare are taken
/// as untyped objects.
pub fn ground(domain: &Domain, problem: &Problem) -> Result<Task, GroundError> {
    ground_within(domain, problem, &GroundLimits::default(), &crate::NoClock)
}

/// [`ground`] within `limits`; time is measured by `clock`.
pub fn ground_within(
    domain: &Domain,
    problem: &Problem,
    limits: &GroundLimits,
    clock: &dyn crate::Clock,
) -> Result<Task, GroundError> {
    let mut fluent_predicates: HashSet<&str> = HashSet::new();
    for action in &domain.actions {
        let outcomes = action.chances.iter().flat_map(|c| &c.outcomes);
        let conditional = action.conditional.iter().flat_map(|c| &c.effects);
        let effects = action.effects.iter().chain(conditional);
        for effect in effects.chain(outcomes.flat_map(|o| &o.items)) {
            if let Effect::Add(a) | Effect::Del(a) = effect {
                fluent_predicates.insert(&a.predicate);
            }
        }
        // What is observed is what the plan branches on: it stays in the state.
        for atom in &action.observe {
            fluent_predicates.insert(&atom.predicate);
        }
    }
    // So is what the initial state is unsure of.
    for atom in problem
        .uncertain
        .iter()
        .flat_map(|u| &u.outcomes)
        .flat_map(|o| &o.items)
    {
        fluent_predicates.insert(&atom.predicate);
    }
    let task = Task {
        predicates: Vec::new(),
        objects: Vec::new(),
        object_ids: HashMap::new(),
        atoms: Vec::new(),
        atom_ids: HashMap::new(),
        static_predicate: Vec::new(),
        statics: HashSet::new(),
        operators: Vec::new(),
        initial: State::empty(0),
        initial_belief: Vec::new(),
        goal: Vec::new(),
        goal_neg: Vec::new(),
        goal_false: Vec::new(),
        arities: domain
            .actions
            .iter()
            .map(|a| (a.name.clone(), a.params.len()))
            .collect(),
        by_first_pre: Vec::new(),
        no_pre: Vec::new(),
        first_variant: Vec::new(),
        next_variant: Vec::new(),
        action_costs: priced_by_effects(domain, problem),
    };
    let mut g = Grounder {
        problem,
        task,
        limits: *limits,
        clock,
        ticks: 0,
        bytes: 0,
        object_types: Vec::new(),
        parents: domain
            .types
            .iter()
            .map(|t| (t.name.clone(), t.parent.clone()))
            .collect(),
        fluent_values: HashMap::new(),
        seen_instances: HashSet::new(),
    };
    for p in &domain.predicates {
        g.predicate(&p.name, &fluent_predicates);
    }
    for object in domain.constants.iter().chain(&problem.objects) {
        let id = g.object(&object.name);
        g.object_types[id as usize] = object.ty.clone().unwrap_or_else(|| "object".into());
    }
    let mut initial_keys = Vec::new();
    for atom in &problem.init {
        let p = g.predicate(&atom.predicate, &fluent_predicates);
        let mut key = vec![p];
        for t in &atom.args {
            match t {
                Term::Const(c) => key.push(g.object(c)),
                Term::Var(v) => return Err(GroundError::VariableInGoal(v.to_string())),
            }
        }
        if g.task.static_predicate[p as usize] {
            g.task.statics.insert(key);
        } else {
            initial_keys.push(key);
        }
    }
    for (call, value) in &problem.numeric_init {
        let mut args = Vec::new();
        for t in &call.args {
            if let Term::Const(c) = t {
                args.push(g.object(c));
            }
        }
        g.fluent_values.insert((call.name.clone(), args), *value);
    }
    let initial_atoms: Vec<AtomId> = initial_keys.into_iter().map(|k| g.intern(k)).collect();
    let uncertain = g.uncertain(&fluent_predicates)?;
    g.goal(&fluent_predicates)?;
    match limits.instances {
        Instances::All => {
            for action in &domain.actions {
                g.seen_instances.clear();
                for schema in g.schemas(action, &fluent_predicates)? {
                    let candidates: Vec<&[u32]> =
                        schema.candidates.iter().map(Vec::as_slice).collect();
                    g.instantiate(&schema, &candidates, &mut |g, binding| {
                        g.emit(&schema, binding)
                    })?;
                }
            }
        }
        Instances::Reachable => {
            let mut schemas = Vec::new();
            for (i, action) in domain.actions.iter().enumerate() {
                for schema in g.schemas(action, &fluent_predicates)? {
                    schemas.push((i, schema));
                }
            }
            let mut start: Vec<AtomId> = initial_atoms.clone();
            start.extend(uncertain.iter().flat_map(|(_, atoms)| atoms));
            let reachable = g.reachable_bindings(&schemas, &start)?;
            // Built in the order grounding every instance builds them, so
            // that the task differs from that one only by what is left out.
            let mut action = None;
            for ((i, schema), bindings) in schemas.iter().zip(reachable) {
                if action != Some(*i) {
                    action = Some(*i);
                    g.seen_instances.clear();
                }
                for binding in bindings.sorted() {
                    g.emit(schema, binding)?;
                }
            }
        }
    }
    let mut task = g.task;
    let mut initial = State::empty(task.atoms.len());
    for a in initial_atoms {
        initial.set(a);
    }
    task.initial_belief = uncertain
        .into_iter()
        .map(|(p, atoms)| {
            let mut state = initial.clone();
            state
                .words
                .resize(task.initial.words.len().max(initial.words.len()), 0);
            for a in atoms {
                state.set(a);
            }
            (p, state)
        })
        .collect();
    task.initial = initial;
    task.index_operators();
    let varied: HashSet<&str> = domain
        .actions
        .iter()
        .filter(|a| !a.alternatives.is_empty() || !a.conditional.is_empty())
        .map(|a| &*a.name)
        .collect();
    task.index_variants(&varied);
    Ok(task)
}

impl Grounder<'_> {
    fn predicate(&mut self, name: &Name, fluent: &HashSet<&str>) -> u32 {
        if let Some(i) = self.task.predicates.iter().position(|p| p == name) {
            return i as u32;
        }
        self.task.predicates.push(name.clone());
        self.task.static_predicate.push(!fluent.contains(&**name));
        (self.task.predicates.len() - 1) as u32
    }

    fn object(&mut self, name: &Name) -> u32 {
        if let Some(&id) = self.task.object_ids.get(name) {
            return id;
        }
        let id = self.task.objects.len() as u32;
        self.task.objects.push(name.clone());
        self.task.object_ids.insert(name.clone(), id);
        self.object_types.push("object".into());
        id
    }

    fn intern(&mut self, key: Vec<u32>) -> AtomId {
        if let Some(&id) = self.task.atom_ids.get(&key) {
            return id;
        }
        let id = AtomId(self.task.atoms.len() as u32);
        self.task.atoms.push(key.clone());
        self.task.atom_ids.insert(key, id);
        id
    }

    /// Whether type `ty` is `ancestor` or one of its subtypes.
    fn is_a(&self, ty: &Name, ancestor: &str) -> bool {
        if ancestor == "object" {
            return true;
        }
        let mut t = ty;
        // The depth bound guards against cycles in a malformed hierarchy.
        for _ in 0..64 {
            if &**t == ancestor {
                return true;
            }
            match self.parents.get(t) {
                Some(p) => t = p,
                None => return false,
            }
        }
        false
    }

    /// The possible worlds of the problem's uncertain facts: for each
    /// combination of outcomes, its probability and the atoms it adds to
    /// the certain init (`[(1, [])]` when nothing is uncertain).
    fn uncertain(
        &mut self,
        fluent: &HashSet<&str>,
    ) -> Result<Vec<(f64, Vec<AtomId>)>, GroundError> {
        let problem = self.problem;
        let mut worlds: Vec<(f64, Vec<AtomId>)> = vec![(1.0, Vec::new())];
        for form in &problem.uncertain {
            let mut outcomes: Vec<(f64, Vec<AtomId>)> = Vec::new();
            for o in &form.outcomes {
                let mut atoms = Vec::new();
                for atom in &o.items {
                    let p = self.predicate(&atom.predicate, fluent);
                    let mut key = vec![p];
                    for t in &atom.args {
                        match t {
                            Term::Const(c) => key.push(self.object(c)),
                            Term::Var(v) => return Err(GroundError::VariableInGoal(v.to_string())),
                        }
                    }
                    atoms.push(self.intern(key));
                }
                outcomes.push((o.probability, atoms));
            }
            outcomes.push((form.rest(), Vec::new()));
            outcomes.retain(|(p, _)| *p > 0.0);
            if worlds.len().saturating_mul(outcomes.len()) > MAX_WORLDS {
                return Err(GroundError::TooUncertain {
                    what: "the initial state".into(),
                    limit: MAX_WORLDS,
                });
            }
            worlds = worlds
                .iter()
                .flat_map(|(p, atoms)| {
                    outcomes.iter().map(move |(q, more)| {
                        let mut all = atoms.clone();
                        all.extend(more);
                        (p * q, all)
                    })
                })
                .collect();
        }
        // Outcomes that add the same atoms are the same world.
        for (_, atoms) in &mut worlds {
            atoms.sort_unstable();
            atoms.dedup();
        }
        worlds.sort_by(|a, b| a.1.cmp(&b.1));
        let mut merged: Vec<(f64, Vec<AtomId>)> = Vec::new();
        for (p, atoms) in worlds {
            match merged.last_mut() {
                Some((q, last)) if *last == atoms => *q += p,
                _ => merged.push((p, atoms)),
            }
        }
        let total: f64 = merged.iter().map(|(p, _)| p).sum();
        for (p, _) in &mut merged {
            *p /= total;
        }
        Ok(merged)
    }

    fn goal(&mut self, fluent: &HashSet<&str>) -> Result<(), GroundError> {
        let problem = self.problem;
        for literal in &problem.goal {
            let mut objects = Vec::new();
            for t in literal.terms() {
                match t {
                    Term::Const(c) => objects.push(self.object(c)),
                    Term::Var(v) => return Err(GroundError::VariableInGoal(v.to_string())),
                }
            }
            match literal {
                Literal::Pos(atom) | Literal::Neg(atom) => {
                    let positive = matches!(literal, Literal::Pos(_));
                    let p = self.predicate(&atom.predicate, fluent);
                    let mut key = vec![p];
                    key.extend(&objects);
                    if self.task.static_predicate[p as usize] {
                        if self.task.statics.contains(&key) != positive {
                            self.task.goal_false.push(literal.to_string());
                        }
                    } else {
                        let id = self.intern(key);
                        if positive {
                            self.task.goal.push(id);
                        } else {
                            self.task.goal_neg.push(id);
                        }
                    }
                }
                Literal::Eq(..) | Literal::Neq(..) => {
                    let equal = objects[0] == objects[1];
                    if equal != matches!(literal, Literal::Eq(..)) {
                        self.task.goal_false.push(literal.to_string());
                    }
                }
            }
        }
        Ok(())
    }

    fn resolve(&mut self, action: &Action, term: &Term) -> Result<Arg, GroundError> {
        match term {
            Term::Const(c) => Ok(Arg::Obj(self.object(c))),
            Term::Var(v) => action
                .params
                .iter()
                .position(|p| p.name == *v)
                .map(Arg::Param)
                .ok_or_else(|| GroundError::UnboundVariable {
                    action: action.name.to_string(),
                    var: v.to_string(),
                }),
        }
    }

    fn resolve_all(&mut self, action: &Action, terms: &[Term]) -> Result<Vec<Arg>, GroundError> {
        terms.iter().map(|t| self.resolve(action, t)).collect()
    }

    /// Compiles `action` for grounding: one schema per disjunct of its
    /// precondition (one for a conjunction).
    fn schemas<'a>(
        &mut self,
        action: &'a Action,
        fluent: &HashSet<&str>,
    ) -> Result<Vec<Schema<'a>>, GroundError> {
        let (effects, costs) = self.compile_effects(action, &action.effects, fluent)?;
        let mut conditional = Vec::new();
        for when in &action.conditional {
            conditional.push(self.compile_effects(action, &when.effects, fluent)?);
        }
        let configure = match &action.configure {
            Some(call) => Some((call, self.resolve_all(action, &call.args)?)),
            None => None,
        };
        let mut chances = Vec::new();
        let mut combinations = 1usize;
        for form in &action.chances {
            let mut outcomes = Vec::new();
            for o in &form.outcomes {
                let mut effects = Vec::new();
                for effect in &o.items {
                    if let Effect::Add(atom) | Effect::Del(atom) = effect {
                        let p = self.predicate(&atom.predicate, fluent);
                        let args = self.resolve_all(action, &atom.args)?;
                        effects.push((matches!(effect, Effect::Add(_)), p, args));
                    }
                }
                outcomes.push((o.probability, effects));
            }
            outcomes.push((form.rest(), Vec::new()));
            outcomes.retain(|(p, _)| *p > 0.0);
            // Outcomes that sum to 1 up to rounding sum to 1 exactly.
            let total: f64 = outcomes.iter().map(|(p, _)| p).sum();
            for (p, _) in &mut outcomes {
                *p /= total;
            }
            combinations = combinations.saturating_mul(outcomes.len());
            chances.push(outcomes);
        }
        if combinations > MAX_OUTCOMES {
            return Err(GroundError::TooUncertain {
                what: format!("action `{}`", action.name),
                limit: MAX_OUTCOMES,
            });
        }
        let mut observe = Vec::new();
        for atom in &action.observe {
            let p = self.predicate(&atom.predicate, fluent);
            observe.push((p, self.resolve_all(action, &atom.args)?));
        }
        let candidates: Vec<Vec<u32>> = action
            .params
            .iter()
            .map(|p| {
                let ty: &str = p.ty.as_deref().unwrap_or("object");
                (0..self.task.objects.len() as u32)
                    .filter(|&o| self.is_a(&self.object_types[o as usize], ty))
                    .collect()
            })
            .collect();
        // One schema per variant: a disjunct of the precondition with one way
        // each `when` condition holds (and its effects happen) or fails.
        let variants = action.variants();
        let mut schemas = Vec::new();
        for variant in &variants {
            let pre = self.compile_precondition(action, &variant.precondition, fluent)?;
            let (mut effects, mut costs) = (effects.clone(), costs.clone());
            for &i in &variant.conditional {
                effects.extend(conditional[i].0.iter().cloned());
                costs.extend(conditional[i].1.iter().cloned());
            }
            schemas.push(Schema {
                action,
                pre,
                effects,
                costs,
                configure: configure.clone(),
                chances: chances.clone(),
                observe: observe.clone(),
                candidates: candidates.clone(),
                variants: (variants.len() > 1).then(|| variant.conditional.clone()),
            });
        }
        Ok(schemas)
    }

    /// Compiles `effects` of `action`: the atoms it adds and deletes as
    /// `(is_add, predicate, args)`, and its cost terms.
    fn compile_effects(
        &mut self,
        action: &Action,
        effects: &[Effect],
        fluent: &HashSet<&str>,
    ) -> Result<(Vec<CEffect>, Vec<CCost>), GroundError> {
        let mut atoms = Vec::new();
        let mut costs = Vec::new();
        for effect in effects {
            match effect {
                Effect::Add(atom) | Effect::Del(atom) => {
                    let p = self.predicate(&atom.predicate, fluent);
                    let args = self.resolve_all(action, &atom.args)?;
                    atoms.push((matches!(effect, Effect::Add(_)), p, args));
                }
                Effect::IncreaseCost(NumExpr::Number(n), _) => costs.push((None, *n, Vec::new())),
                Effect::IncreaseCost(NumExpr::Function(call), _) => {
                    let args = self.resolve_all(action, &call.args)?;
                    costs.push((Some(call.name.clone()), 0, args));
                }
            }
        }
        Ok((atoms, costs))
    }

    /// Compiles a conjunction of `action`'s literals: a variant's precondition.
    fn compile_precondition(
        &mut self,
        action: &Action,
        literals: &[Literal],
        fluent: &HashSet<&str>,
    ) -> Result<Precondition, GroundError> {
        let mut lits = Vec::new();
        for literal in literals {
            lits.push(match literal {
                Literal::Pos(atom) | Literal::Neg(atom) => CLit::Atom {
                    positive: matches!(literal, Literal::Pos(_)),
                    predicate: self.predicate(&atom.predicate, fluent),
                    args: self.resolve_all(action, &atom.args)?,
                },
                Literal::Eq(a, b, _) | Literal::Neq(a, b, _) => CLit::Eq {
                    positive: matches!(literal, Literal::Eq(..)),
                    a: self.resolve(action, a)?,
                    b: self.resolve(action, b)?,
                },
            });
        }
        let n = action.params.len();
        let mut checks: Vec<Vec<usize>> = vec![Vec::new(); n + 1];
        let mut dynamic = Vec::new();
        for (i, lit) in lits.iter().enumerate() {
            let (is_static, args): (bool, Vec<Arg>) = match lit {
                CLit::Atom {
                    predicate, args, ..
                } => (
                    self.task.static_predicate[*predicate as usize],
                    args.clone(),
                ),
                CLit::Eq { a, b, .. } => (true, vec![*a, *b]),
            };
            if is_static {
                let level = args
                    .iter()
                    .filter_map(|a| match a {
                        Arg::Param(p) => Some(p + 1),
                        Arg::Obj(_) => None,
                    })
                    .max()
                    .unwrap_or(0);
                checks[level].push(i);
            } else {
                dynamic.push(i);
            }
        }
        Ok(Precondition {
            lits,
            dynamic,
            checks,
        })
    }

    /// Calls `found` with every binding of `schema`'s parameters to
    /// `candidates` (one list per parameter, each in increasing order) that
    /// passes its static checks, in lexicographic order.
    fn instantiate<F>(
        &mut self,
        schema: &Schema<'_>,
        candidates: &[&[u32]],
        found: &mut F,
    ) -> Result<(), GroundError>
    where
        F: FnMut(&mut Self, &[u32]) -> Result<(), GroundError>,
    {
        let n = candidates.len();
        let Precondition { lits, checks, .. } = &schema.pre;
        let mut binding = vec![0u32; n];
        if !checks[0].iter().all(|&i| self.holds(&lits[i], &binding)) {
            return Ok(());
        }
        // An odometer over the candidates, iterative so that no schema can
        // overflow the stack.
        let mut cursor = vec![0usize; n];
        let mut depth = 0;
        if n == 0 {
            return found(self, &binding);
        }
        loop {
            if cursor[depth] == candidates[depth].len() {
                if depth == 0 {
                    return Ok(());
                }
                cursor[depth] = 0;
                depth -= 1;
                cursor[depth] += 1;
                continue;
            }
            binding[depth] = candidates[depth][cursor[depth]];
            self.tick()?;
            if !checks[depth + 1]
                .iter()
                .all(|&i| self.holds(&lits[i], &binding))
            {
                cursor[depth] += 1;
                continue;
            }
            if depth + 1 < n {
                depth += 1;
                continue;
            }
            found(self, &binding)?;
            cursor[depth] += 1;
        }
    }

    /// Counts one binding tried; every [`CLOCK_EVERY`] of them, checks the time.
    fn tick(&mut self) -> Result<(), GroundError> {
        self.ticks += 1;
        if self.ticks >= CLOCK_EVERY {
            self.ticks = 0;
            if let Some(limit) = self.limits.max_time
                && self.clock.elapsed() >= limit
            {
                return Err(GroundError::OutOfTime { limit });
            }
        }
        Ok(())
    }

    fn holds(&self, lit: &CLit, binding: &[u32]) -> bool {
        let value = |a: &Arg| match *a {
            Arg::Param(p) => binding[p],
            Arg::Obj(o) => o,
        };
        match lit {
            CLit::Atom {
                positive,
                predicate,
                args,
            } => {
                let mut key = Vec::with_capacity(args.len() + 1);
                key.push(*predicate);
                key.extend(args.iter().map(value));
                self.task.statics.contains(&key) == *positive
            }
            CLit::Eq { positive, a, b } => (value(a) == value(b)) == *positive,
        }
    }

    fn emit(&mut self, schema: &Schema<'_>, binding: &[u32]) -> Result<(), GroundError> {
        let Schema {
            action,
            pre: Precondition { lits, dynamic, .. },
            effects,
            costs,
            configure,
            chances,
            observe,
            variants,
            ..
        } = schema;
        if self.task.operators.len() >= self.limits.max_operators {
            return Err(GroundError::TooLarge {
                limit: self.limits.max_operators,
            });
        }
        let value = |a: &Arg| match *a {
            Arg::Param(p) => binding[p],
            Arg::Obj(o) => o,
        };
        let cost = if self.task.action_costs {
            let mut total = 0u64;
            for (function, n, args) in costs {
                match function {
                    None => total = total.saturating_add(*n),
                    Some(name) => {
                        let key = (name.clone(), args.iter().map(value).collect());
                        // An undefined fluent makes the action inapplicable (PDDL).
                        let Some(&v) = self.fluent_values.get(&key) else {
                            return Ok(());
                        };
                        total = total.saturating_add(v);
                    }
                }
            }
            total
        } else {
            1
        };
        let mut pre = Vec::new();
        let mut pre_neg = Vec::new();
        for &i in dynamic {
            if let CLit::Atom {
                positive,
                predicate,
                args,
            } = &lits[i]
            {
                let mut key = vec![*predicate];
                key.extend(args.iter().map(value));
                let id = self.intern(key);
                if *positive {
                    pre.push(id);
                } else {
                    pre_neg.push(id);
                }
            }
        }
        pre.sort_unstable();
        pre.dedup();
        pre_neg.sort_unstable();
        pre_neg.dedup();
        if pre.iter().any(|a| pre_neg.contains(a)) {
            return Ok(());
        }
        // Variants that differ only in static literals give the same operator.
        if let Some(conditional) = variants
            && !self.seen_instances.insert((
                conditional.clone(),
                binding.to_vec(),
                pre.clone(),
                pre_neg.clone(),
            ))
        {
            return Ok(());
        }
        let mut add = Vec::new();
        let mut del = Vec::new();
        for (is_add, predicate, args) in effects {
            let mut key = vec![*predicate];
            key.extend(args.iter().map(value));
            let id = self.intern(key);
            if *is_add { &mut add } else { &mut del }.push(id);
        }
        // Every combination of the `probabilistic` forms' outcomes, each
        // with the common effects: adding wins over deleting within it.
        let mut outcomes: Vec<Chance> = Vec::new();
        if !chances.is_empty() {
            let mut combos: Vec<(f64, Vec<AtomId>, Vec<AtomId>)> =
                vec![(1.0, add.clone(), del.clone())];
            for form in chances {
                let mut next = Vec::with_capacity(combos.len() * form.len());
                for (p, a, d) in &combos {
                    for (q, effects) in form {
                        let (mut a, mut d) = (a.clone(), d.clone());
                        for (is_add, predicate, args) in effects {
                            let mut key = vec![*predicate];
                            key.extend(args.iter().map(value));
                            let id = self.intern(key);
                            if *is_add { &mut a } else { &mut d }.push(id);
                        }
                        next.push((p * q, a, d));
                    }
                }
                combos = next;
            }
            for (probability, mut a, mut d) in combos {
                a.sort_unstable();
                a.dedup();
                d.sort_unstable();
                d.dedup();
                d.retain(|x| !a.contains(x));
                match outcomes.iter_mut().find(|o| o.add == a && o.del == d) {
                    Some(same) => same.probability += probability,
                    None => outcomes.push(Chance {
                        probability,
                        add: a,
                        del: d,
                    }),
                }
            }
        }
        add.sort_unstable();
        add.dedup();
        del.sort_unstable();
        del.dedup();
        del.retain(|a| !add.contains(a));
        if outcomes.len() == 1 {
            // Every outcome does the same: a deterministic operator.
            let only = outcomes.pop().unwrap_or_else(|| unreachable!());
            add = only.add;
            del = only.del;
        } else {
            // What every outcome does, for code that reads `add`/`del`.
            let first = outcomes.first().map(|o| (o.add.clone(), o.del.clone()));
            if let Some((mut a, mut d)) = first {
                a.retain(|x| outcomes.iter().all(|o| o.add.contains(x)));
                d.retain(|x| outcomes.iter().all(|o| o.del.contains(x)));
                add = a;
                del = d;
            }
        }
        let mut observed = Vec::new();
        for (predicate, args) in observe {
            let mut key = vec![*predicate];
            key.extend(args.iter().map(value));
            observed.push(self.intern(key));
        }
        observed.dedup();
        let configure = configure.as_ref().map(|(call, args)| Call {
            name: call.name.clone(),
            args: args
                .iter()
                .map(|a| Term::Const(self.task.objects[value(a) as usize].clone()))
                .collect(),
            span: call.span,
        });
        let operator = Operator {
            action: action.name.clone(),
            args: binding
                .iter()
                .map(|&o| self.task.objects[o as usize].clone())
                .collect(),
            pre,
            pre_neg,
            add,
            del,
            cost,
            configure,
            outcomes,
            observe: observed,
        };
        self.bytes = self.bytes.saturating_add(operator_bytes(&operator));
        if self.bytes > self.limits.max_bytes {
            return Err(GroundError::TooMuchMemory {
                limit_mib: self.limits.max_bytes / (1024 * 1024),
            });
        }
        self.task.operators.push(operator);
        Ok(())
    }
}

/// About how many bytes `op` holds, its heap allocations included.
fn operator_bytes(op: &Operator) -> usize {
    let names = |names: &[Name]| {
        names
            .iter()
            .map(|n| n.len() + 2 * size_of::<usize>())
            .sum::<usize>()
    };
    let atoms = op.pre.len()
        + op.pre_neg.len()
        + op.add.len()
        + op.del.len()
        + op.observe.len()
        + op.outcomes
            .iter()
            .map(|o| o.add.len() + o.del.len() + 4)
            .sum::<usize>();
    let configure = op.configure.as_ref().map_or(0, |c| {
        c.name.len() + c.args.len() * (size_of::<Term>() + 16)
    });
    size_of::<Operator>()
        + op.action.len()
        + names(&op.args)
        + atoms * size_of::<AtomId>()
        + configure
}
