//! The validated domain model: functionalities, tasks, methods, actions, problems.
//!
//! These types are plain data produced by the parser (`crate::parse_domain`,
//! `crate::parse_problem`). Every item keeps the span of its source text so later
//! stages (the planners, the CLI) can point at it.

use std::collections::HashMap;
use std::fmt;

use crate::diagnostic::Span;
use crate::format::Information;

/// A name: a symbol of the language, lowercased.
pub type Name = std::sync::Arc<str>;

/// An argument: a variable (`?r`, stored without the `?`) or a constant (`astrid`, `25`).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Term {
    /// `?name`
    Var(Name),
    /// A symbol or number.
    Const(Name),
}

impl Term {
    /// The variable's name, if this is a variable.
    pub fn var(&self) -> Option<&str> {
        match self {
            Term::Var(name) => Some(name),
            Term::Const(_) => None,
        }
    }
}

impl fmt::Display for Term {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Term::Var(name) => write!(f, "?{name}"),
            Term::Const(name) => f.write_str(name),
        }
    }
}

/// Writes `(head a b c)`.
pub(crate) fn write_call(
    f: &mut fmt::Formatter<'_>,
    head: &str,
    args: &[impl fmt::Display],
) -> fmt::Result {
    write!(f, "({head}")?;
    for arg in args {
        write!(f, " {arg}")?;
    }
    f.write_str(")")
}

/// A predicate applied to arguments: `(pc ?p tr-sys ?t)`.
#[derive(Debug, Clone, PartialEq)]
pub struct Atom {
    /// The predicate's name.
    pub predicate: Name,
    /// Its arguments.
    pub args: Vec<Term>,
    /// The whole atom in the source.
    pub span: Span,
}

impl fmt::Display for Atom {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_call(f, &self.predicate, &self.args)
    }
}

/// One conjunct of a condition.
#[derive(Debug, Clone, PartialEq)]
pub enum Literal {
    /// The atom holds.
    Pos(Atom),
    /// The atom does not hold (closed world).
    Neg(Atom),
    /// `(= a b)`
    Eq(Term, Term, Span),
    /// `(not (= a b))`
    Neq(Term, Term, Span),
}

impl Literal {
    /// Where the literal stands in the source.
    pub fn span(&self) -> Span {
        match self {
            Literal::Pos(atom) | Literal::Neg(atom) => atom.span,
            Literal::Eq(_, _, span) | Literal::Neq(_, _, span) => *span,
        }
    }

    /// Every term the literal mentions.
    pub fn terms(&self) -> impl Iterator<Item = &Term> {
        let (slice, pair): (&[Term], Option<[&Term; 2]>) = match self {
            Literal::Pos(atom) | Literal::Neg(atom) => (&atom.args, None),
            Literal::Eq(a, b, _) | Literal::Neq(a, b, _) => (&[], Some([a, b])),
        };
        slice.iter().chain(pair.into_iter().flatten())
    }
}

impl Literal {
    /// The literal that holds exactly when this one does not.
    pub fn negated(&self) -> Literal {
        match self {
            Literal::Pos(atom) => Literal::Neg(atom.clone()),
            Literal::Neg(atom) => Literal::Pos(atom.clone()),
            Literal::Eq(a, b, span) => Literal::Neq(a.clone(), b.clone(), *span),
            Literal::Neq(a, b, span) => Literal::Eq(a.clone(), b.clone(), *span),
        }
    }
}

impl fmt::Display for Literal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Literal::Pos(atom) => write!(f, "{atom}"),
            Literal::Neg(atom) => write!(f, "(not {atom})"),
            Literal::Eq(a, b, _) => write!(f, "(= {a} {b})"),
            Literal::Neq(a, b, _) => write!(f, "(not (= {a} {b}))"),
        }
    }
}

/// A schema parameter: `?r`, or `?r - robot` with `:typing`.
#[derive(Debug, Clone, PartialEq)]
pub struct Param {
    /// The name without `?` (or the object's name, for `:objects` and `:constants`).
    pub name: Name,
    /// Its type, when typed.
    pub ty: Option<Name>,
    /// Where it is declared.
    pub span: Span,
}

/// A named thing applied to arguments: a subtask `(cameras ?p ?c)`, a goal
/// `(navigate astrid bedroom)`, a `:configure` goal, a numeric function term.
#[derive(Debug, Clone, PartialEq)]
pub struct Call {
    /// What is called.
    pub name: Name,
    /// The arguments.
    pub args: Vec<Term>,
    /// The whole call in the source.
    pub span: Span,
}

impl fmt::Display for Call {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_call(f, &self.name, &self.args)
    }
}

/// An information type on an input or output: `(image ?p)`, optionally with a
/// rate `(image ?p :hz 25)`.
#[derive(Debug, Clone, PartialEq)]
pub struct Info {
    /// The kind of information.
    pub name: Name,
    /// Whose or what it is about.
    pub args: Vec<Term>,
    /// For an output, the rate offered; for an input, the rate required.
    pub hz: Option<f64>,
    /// Where it is written.
    pub span: Span,
}

impl fmt::Display for Info {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "({}", self.name)?;
        for arg in &self.args {
            write!(f, " {arg}")?;
        }
        if let Some(hz) = self.hz {
            write!(f, " :hz {hz}")?;
        }
        f.write_str(")")
    }
}

/// A functionality (the paper's operator schema), implemented by a PEIS-component.
#[derive(Debug, Clone, PartialEq)]
pub struct Functionality {
    /// Its name, also how subtasks call it.
    pub name: Name,
    /// Its parameters, all bound by the caller.
    pub params: Vec<Param>,
    /// The parameters naming the PEIS and the component that implement it.
    pub component: (Name, Name),
    /// Conditions on the ecology state.
    pub precondition: Vec<Literal>,
    /// Information it reads.
    pub inputs: Vec<Info>,
    /// Information it produces.
    pub outputs: Vec<Info>,
    /// Conditions it achieves in the world (`done` once they hold).
    pub postcondition: Vec<Literal>,
    /// Its default cost, used when the state has no cost fact for the component.
    pub cost: u64,
    /// The whole `(:functionality ...)` form.
    pub span: Span,
    /// The name in the source.
    pub name_span: Span,
}

/// A task: something methods decompose, with the information it takes and gives.
#[derive(Debug, Clone, PartialEq)]
pub struct Task {
    /// Its name.
    pub name: Name,
    /// Its parameters.
    pub params: Vec<Param>,
    /// Declared inputs, if any (each method must deliver them to a subtask).
    pub inputs: Vec<Info>,
    /// Declared outputs, if any (each method must provide them).
    pub outputs: Vec<Info>,
    /// The whole `(:task ...)` form.
    pub span: Span,
    /// The name in the source.
    pub name_span: Span,
}

/// A labelled subtask of a method: `(f1 (cameras ?p ?c))`.
#[derive(Debug, Clone, PartialEq)]
pub struct Subtask {
    /// The label, unique in its method.
    pub label: Name,
    /// The task or functionality it calls.
    pub call: Call,
    /// The whole subtask in the source.
    pub span: Span,
}

/// A channel between two subtasks of a method: `(f1 f2 (image ?p))`.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelSpec {
    /// The producing subtask's label.
    pub from: Name,
    /// The consuming subtask's label.
    pub to: Name,
    /// The information carried.
    pub info: Info,
    /// The whole channel in the source.
    pub span: Span,
}

/// A method's `:inputs`/`:outputs` entry: the task's information is that of a subtask.
#[derive(Debug, Clone, PartialEq)]
pub struct Redirect {
    /// The information.
    pub info: Info,
    /// The subtask that consumes (for `:inputs`) or produces (for `:outputs`) it.
    pub label: Name,
    /// The entry in the source.
    pub span: Span,
}

/// A method (the paper's config-method): one way to decompose a task.
#[derive(Debug, Clone, PartialEq)]
pub struct Method {
    /// Its name.
    pub name: Name,
    /// Its variables.
    pub params: Vec<Param>,
    /// The task it decomposes, with arguments in terms of its variables.
    pub task: Call,
    /// Conditions on the ecology state; positive atoms bind variables.
    pub precondition: Vec<Literal>,
    /// The subtasks, by label.
    pub subtasks: Vec<Subtask>,
    /// Channels between subtasks.
    pub channels: Vec<ChannelSpec>,
    /// Which subtask consumes each input of the task.
    pub inputs: Vec<Redirect>,
    /// Which subtask produces each output of the task.
    pub outputs: Vec<Redirect>,
    /// The whole `(:method ...)` form.
    pub span: Span,
    /// The name in the source.
    pub name_span: Span,
}

impl Method {
    /// The subtask with `label`.
    pub fn subtask(&self, label: &str) -> Option<&Subtask> {
        self.subtasks.iter().find(|s| &*s.label == label)
    }
}

/// A numeric expression in an action cost: a number or a function term.
#[derive(Debug, Clone, PartialEq)]
pub enum NumExpr {
    /// A constant amount.
    Number(u64),
    /// A numeric fluent such as `(road-length ?from ?to)`, valued in the problem's `:init`.
    Function(Call),
}

/// One effect of an action.
#[derive(Debug, Clone, PartialEq)]
pub enum Effect {
    /// The atom becomes true.
    Add(Atom),
    /// The atom becomes false.
    Del(Atom),
    /// `(increase (total-cost) AMOUNT)`
    IncreaseCost(NumExpr, Span),
}

/// `(when CONDITION EFFECT)`: effects that happen only when the condition
/// holds in the state the action is applied in.
#[derive(Debug, Clone, PartialEq)]
pub struct Conditional {
    /// A conjunction, read in the state before the action.
    pub condition: Vec<Literal>,
    /// What then happens, with the action's other effects.
    pub effects: Vec<Effect>,
    /// The whole `when` form.
    pub span: Span,
}

/// One outcome of a `(probabilistic ...)` form: its probability and what
/// then happens (effects in an action, atoms in a problem's `:init`).
#[derive(Debug, Clone, PartialEq)]
pub struct Weighted<T> {
    /// In `[0, 1]`.
    pub probability: f64,
    /// The effects or atoms of this outcome (a conjunction).
    pub items: Vec<T>,
    /// The outcome in the source.
    pub span: Span,
}

/// `(probabilistic P1 X1 P2 X2 ...)` or `(oneof X1 X2 ...)`: exactly one
/// outcome happens, outcome `i` with probability `Pi`; with probability
/// `1 - sum(Pi)` none does (nothing changes).
#[derive(Debug, Clone, PartialEq)]
pub struct Probabilistic<T> {
    /// The outcomes; their probabilities sum to at most 1.
    pub outcomes: Vec<Weighted<T>>,
    /// The whole form.
    pub span: Span,
}

impl<T> Probabilistic<T> {
    /// The probability that no outcome happens: 0 when the outcomes sum to
    /// 1 up to [`crate::PROBABILITY_EPSILON`] (0.7 + 0.2 + 0.1 is
    /// 0.9999999999999999 in binary, and its leftover is rounding, not an
    /// outcome).
    pub fn rest(&self) -> f64 {
        let rest = 1.0 - self.outcomes.iter().map(|o| o.probability).sum::<f64>();
        if rest <= crate::PROBABILITY_EPSILON {
            0.0
        } else {
            rest
        }
    }
}

/// An action schema for the action planner.
#[derive(Debug, Clone, PartialEq)]
pub struct Action {
    /// Its name.
    pub name: Name,
    /// Its parameters (typed with `:typing`).
    pub params: Vec<Param>,
    /// Conditions on the world state: the conjunction every application needs.
    pub precondition: Vec<Literal>,
    /// The disjunctive rest of the precondition (`or`, `imply`, a negated `and`) in
    /// disjunctive normal form, negation pushed onto atoms: besides `precondition`, one of
    /// these conjunctions must hold. Empty when the precondition is a conjunction.
    pub alternatives: Vec<Vec<Literal>>,
    /// What it changes.
    pub effects: Vec<Effect>,
    /// `(when ...)` effects: what it changes besides when their conditions
    /// hold. Empty when it has none.
    pub conditional: Vec<Conditional>,
    /// The configuration goal that performs it, if any.
    pub configure: Option<Call>,
    /// `(probabilistic P1 E1 P2 E2 ...)` effects: each picks one of its
    /// outcomes independently of the others, on top of `effects`, which
    /// always happen. Empty for a deterministic action.
    pub chances: Vec<Probabilistic<Effect>>,
    /// `:observe`: the atoms whose truth the action reveals, read in the
    /// state after its effects (a sensing action). Empty when it senses nothing.
    pub observe: Vec<Atom>,
    /// The whole `(:action ...)` form.
    pub span: Span,
    /// The name in the source.
    pub name_span: Span,
}

/// One way an action can apply, with what it then does: a disjunct of its
/// precondition combined with one way each of its `when` conditions holds
/// (all its literals) or fails (one of them false).
#[derive(Debug, Clone, PartialEq)]
pub struct Variant {
    /// The whole precondition of this variant, a conjunction.
    pub precondition: Vec<Literal>,
    /// The `when` effects that happen, by index into [`Action::conditional`].
    pub conditional: Vec<usize>,
}

impl Action {
    /// How many variants [`Action::variants`] lists.
    pub fn variant_count(&self) -> usize {
        self.conditional
            .iter()
            .fold(self.alternatives.len().max(1), |n, c| {
                n.saturating_mul(1 + c.condition.len())
            })
    }

    /// Every variant of the action: together they apply exactly where the
    /// action does, and each does what the action does there. Operators of
    /// a planner without disjunctions or conditional effects.
    pub fn variants(&self) -> Vec<Variant> {
        let no_alternative = [Vec::new()];
        let disjuncts = if self.alternatives.is_empty() {
            &no_alternative[..]
        } else {
            &self.alternatives[..]
        };
        let mut variants: Vec<Variant> = disjuncts
            .iter()
            .map(|disjunct| Variant {
                precondition: self.precondition.iter().chain(disjunct).cloned().collect(),
                conditional: Vec::new(),
            })
            .collect();
        for (i, when) in self.conditional.iter().enumerate() {
            let mut next = Vec::new();
            for variant in variants {
                let mut holds = variant.clone();
                holds.precondition.extend(when.condition.iter().cloned());
                holds.conditional.push(i);
                next.push(holds);
                for literal in &when.condition {
                    let mut fails = variant.clone();
                    fails.precondition.push(literal.negated());
                    next.push(fails);
                }
            }
            variants = next;
        }
        variants
    }
}

/// A declared predicate or numeric function: `(at ?r - robot ?x - room)`.
#[derive(Debug, Clone, PartialEq)]
pub struct PredicateDecl {
    /// Its name.
    pub name: Name,
    /// Its parameters.
    pub params: Vec<Param>,
    /// Where it is declared.
    pub span: Span,
}

/// A declared type and its parent (`object` when none is given).
#[derive(Debug, Clone, PartialEq)]
pub struct TypeDecl {
    /// The type.
    pub name: Name,
    /// Its supertype.
    pub parent: Name,
    /// Where it is declared.
    pub span: Span,
}

/// A parsed and validated domain.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Domain {
    /// `(domain NAME)`
    pub name: Name,
    /// `(:requirements ...)`, without the colons.
    pub requirements: Vec<Name>,
    /// `(:types ...)`
    pub types: Vec<TypeDecl>,
    /// `(:constants ...)`
    pub constants: Vec<Param>,
    /// `(:predicates ...)`
    pub predicates: Vec<PredicateDecl>,
    /// `(:functions ...)`
    pub functions: Vec<PredicateDecl>,
    /// `(:functionality ...)` forms.
    pub functionalities: Vec<Functionality>,
    /// `(:task ...)` forms.
    pub tasks: Vec<Task>,
    /// `(:method ...)` forms.
    pub methods: Vec<Method>,
    /// `(:action ...)` forms.
    pub actions: Vec<Action>,
    /// `(:information ...)` forms: the declared value formats.
    pub information: Vec<Information>,
    pub(crate) index: Index,
}

/// Name lookups, built once by validation.
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct Index {
    pub(crate) functionalities: HashMap<Name, usize>,
    pub(crate) tasks: HashMap<Name, usize>,
    pub(crate) actions: HashMap<Name, usize>,
    pub(crate) methods_of_task: HashMap<Name, Vec<usize>>,
}

impl Domain {
    /// The functionality called `name`.
    pub fn functionality(&self, name: &str) -> Option<&Functionality> {
        self.index
            .functionalities
            .get(name)
            .map(|&i| &self.functionalities[i])
    }

    /// The task called `name`.
    pub fn task(&self, name: &str) -> Option<&Task> {
        self.index.tasks.get(name).map(|&i| &self.tasks[i])
    }

    /// The action called `name`.
    pub fn action(&self, name: &str) -> Option<&Action> {
        self.index.actions.get(name).map(|&i| &self.actions[i])
    }

    /// The methods that decompose task `name`, in source order.
    pub fn methods_of(&self, name: &str) -> impl Iterator<Item = &Method> {
        self.index
            .methods_of_task
            .get(name)
            .into_iter()
            .flatten()
            .map(|&i| &self.methods[i])
    }

    /// Whether the domain declares `requirement` (without the colon).
    pub fn requires(&self, requirement: &str) -> bool {
        self.requirements.iter().any(|r| &**r == requirement)
    }
}

/// The metric of a problem.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Metric {
    /// `(:metric minimize (total-cost))`
    MinimizeTotalCost,
}

/// A planning problem: `(define (problem NAME) (:domain NAME) ...)`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Problem {
    /// `(problem NAME)`
    pub name: Name,
    /// `(:domain NAME)`
    pub domain: Name,
    /// Where the domain's name stands in the problem.
    pub domain_span: Span,
    /// `(:objects ...)`
    pub objects: Vec<Param>,
    /// The ground atoms of `(:init ...)`.
    pub init: Vec<Atom>,
    /// Numeric fluents of `(:init ...)`: `(= (road-length a b) 5)`.
    pub numeric_init: Vec<(Call, u64)>,
    /// Uncertain facts of `(:init ...)`: `(probabilistic 0.7 (at n e) 0.3 (at n k))`
    /// or `(oneof ...)`, each independent of the others; the initial state is
    /// `init` plus one outcome of each (a distribution over possible worlds).
    pub uncertain: Vec<Probabilistic<Atom>>,
    /// `(:goal ...)`, a conjunction.
    pub goal: Vec<Literal>,
    /// `(:metric ...)`, if given.
    pub metric: Option<Metric>,
}
