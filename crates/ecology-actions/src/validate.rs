//! The plan validator: applies each action of a plan to the problem's initial
//! state by the schemas' own semantics, checking its preconditions, then
//! checks the goal.
//!
//! It works on the lifted model (`Domain`, `Problem`) with names, not on the
//! ground [`crate::Task`], so it is independent of grounding and search and
//! can check their output, or a plan from anywhere else.

use std::collections::{BTreeSet, HashMap};

use ecology_domain::{Action, Call, Domain, Effect, Literal, Name, NumExpr, Problem, Term};

/// A ground atom by names.
pub(crate) type Fact = (Name, Vec<Name>);

/// The world: the ground atoms that hold.
pub(crate) type World = BTreeSet<Fact>;

/// Why a plan is not valid. Steps count from 1.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PlanError {
    /// No action schema has the step's name.
    #[error("step {step}: unknown action `{action}`")]
    UnknownAction {
        /// The step.
        step: usize,
        /// The name given.
        action: String,
    },
    /// The step has the wrong number of arguments.
    #[error("step {step}: `{action}` takes {expected} arguments, given {given}")]
    Arity {
        /// The step.
        step: usize,
        /// The action.
        action: String,
        /// Its parameter count.
        expected: usize,
        /// Arguments given.
        given: usize,
    },
    /// An argument is not an object of the parameter's type.
    #[error("step {step}: `{arg}` is not an object of type `{ty}`")]
    BadArgument {
        /// The step.
        step: usize,
        /// The argument.
        arg: String,
        /// The parameter's type.
        ty: String,
    },
    /// A precondition does not hold when the step is applied.
    #[error("step {step}: precondition {literal} of {call} does not hold")]
    Precondition {
        /// The step.
        step: usize,
        /// The step, as written.
        call: String,
        /// The ground literal that fails.
        literal: String,
    },
    /// A cost refers to a numeric fluent the problem does not define.
    #[error("step {step}: the cost of {call} uses {function}, which `:init` does not define")]
    UndefinedCost {
        /// The step.
        step: usize,
        /// The step, as written.
        call: String,
        /// The ground function term.
        function: String,
    },
    /// After the last step, the goal does not hold.
    #[error("the goal does not hold at the end: {}", .literals.join(" "))]
    GoalNotReached {
        /// The ground goal literals that fail.
        literals: Vec<String>,
    },
}

/// The lifted semantics of a domain and a problem.
#[derive(Debug)]
pub(crate) struct Semantics<'a> {
    pub(crate) domain: &'a Domain,
    pub(crate) problem: &'a Problem,
    /// Each object and constant with its type.
    pub(crate) objects: Vec<(Name, Name)>,
    parents: HashMap<Name, Name>,
    fluents: HashMap<(Name, Vec<Name>), u64>,
}

fn write_fact(name: &str, args: &[Name]) -> String {
    let mut out = format!("({name}");
    for a in args {
        out.push(' ');
        out.push_str(a);
    }
    out.push(')');
    out
}

/// Each parameter of `action` by name, bound to its argument in `args`.
pub(crate) fn binding<'b>(action: &'b Action, args: &'b [Name]) -> HashMap<&'b str, &'b Name> {
    action.params.iter().map(|p| &*p.name).zip(args).collect()
}

impl<'a> Semantics<'a> {
    pub(crate) fn new(domain: &'a Domain, problem: &'a Problem) -> Semantics<'a> {
        let objects = domain
            .constants
            .iter()
            .chain(&problem.objects)
            .map(|p| {
                (
                    p.name.clone(),
                    p.ty.clone().unwrap_or_else(|| "object".into()),
                )
            })
            .collect();
        let fluents = problem
            .numeric_init
            .iter()
            .map(|(call, v)| {
                let args = call
                    .args
                    .iter()
                    .map(|t| match t {
                        Term::Const(c) | Term::Var(c) => c.clone(),
                    })
                    .collect();
                ((call.name.clone(), args), *v)
            })
            .collect();
        Semantics {
            domain,
            problem,
            objects,
            parents: domain
                .types
                .iter()
                .map(|t| (t.name.clone(), t.parent.clone()))
                .collect(),
            fluents,
        }
    }

    pub(crate) fn initial(&self) -> World {
        self.problem
            .init
            .iter()
            .map(|a| {
                (
                    a.predicate.clone(),
                    a.args
                        .iter()
                        .map(|t| match t {
                            Term::Const(c) | Term::Var(c) => c.clone(),
                        })
                        .collect(),
                )
            })
            .collect()
    }

    /// Every argument tuple of `action`: each parameter bound to every
    /// object of its type (`object` when untyped), the first parameter
    /// varying slowest.
    pub(crate) fn arguments(&self, action: &Action) -> Vec<Vec<Name>> {
        let mut tuples: Vec<Vec<Name>> = vec![Vec::new()];
        for param in &action.params {
            let ty = param.ty.as_deref().unwrap_or("object");
            let fits: Vec<&Name> = self
                .objects
                .iter()
                .map(|(n, _)| n)
                .filter(|n| self.has_type(n, ty))
                .collect();
            tuples = tuples
                .into_iter()
                .flat_map(|t| {
                    fits.iter().map(move |o| {
                        let mut t = t.clone();
                        t.push((*o).clone());
                        t
                    })
                })
                .collect();
        }
        tuples
    }

    /// Whether object `name` has type `ty` (or a subtype of it).
    pub(crate) fn has_type(&self, name: &str, ty: &str) -> bool {
        let Some((_, own)) = self.objects.iter().find(|(n, _)| &**n == name) else {
            return false;
        };
        let mut t: &Name = own;
        for _ in 0..64 {
            if ty == "object" || &**t == ty {
                return true;
            }
            match self.parents.get(t) {
                Some(p) => t = p,
                None => return false,
            }
        }
        false
    }

    fn ground(term: &Term, bind: &HashMap<&str, &Name>) -> Name {
        match term {
            Term::Const(c) => c.clone(),
            Term::Var(v) => bind.get(&**v).map_or_else(|| v.clone(), |n| (*n).clone()),
        }
    }

    fn literal_holds(
        literal: &Literal,
        bind: &HashMap<&str, &Name>,
        world: &World,
    ) -> Result<(), String> {
        let (ok, text) = Self::literal_truth(literal, bind, world);
        if ok { Ok(()) } else { Err(text) }
    }

    /// Whether `literal` holds in `world`, and the ground literal as text.
    fn literal_truth(
        literal: &Literal,
        bind: &HashMap<&str, &Name>,
        world: &World,
    ) -> (bool, String) {
        let ground_all =
            |args: &[Term]| -> Vec<Name> { args.iter().map(|t| Self::ground(t, bind)).collect() };
        match literal {
            Literal::Pos(atom) => {
                let args = ground_all(&atom.args);
                let text = write_fact(&atom.predicate, &args);
                (world.contains(&(atom.predicate.clone(), args)), text)
            }
            Literal::Neg(atom) => {
                let args = ground_all(&atom.args);
                let text = format!("(not {})", write_fact(&atom.predicate, &args));
                (!world.contains(&(atom.predicate.clone(), args)), text)
            }
            Literal::Eq(a, b, _) => {
                let (a, b) = (Self::ground(a, bind), Self::ground(b, bind));
                (a == b, format!("(= {a} {b})"))
            }
            Literal::Neq(a, b, _) => {
                let (a, b) = (Self::ground(a, bind), Self::ground(b, bind));
                (a != b, format!("(not (= {a} {b}))"))
            }
        }
    }

    /// `(or ...)` of the ground `disjuncts`, each a literal or `(and ...)`.
    fn disjunction_text(
        disjuncts: &[Vec<Literal>],
        bind: &HashMap<&str, &Name>,
        world: &World,
    ) -> String {
        let mut out = String::from("(or");
        for disjunct in disjuncts {
            let literals: Vec<String> = disjunct
                .iter()
                .map(|l| Self::literal_truth(l, bind, world).1)
                .collect();
            match &literals[..] {
                [one] => out.push_str(&format!(" {one}")),
                many => out.push_str(&format!(" (and {})", many.join(" "))),
            }
        }
        out.push(')');
        out
    }

    /// The effects of `action` under `bind` applied to `world`: its own, and
    /// those of each `when` whose condition holds in `world`.
    pub(crate) fn effects_in<'e>(
        action: &'e Action,
        bind: &HashMap<&str, &Name>,
        world: &World,
    ) -> Vec<&'e Effect> {
        let mut effects: Vec<&Effect> = action.effects.iter().collect();
        for when in &action.conditional {
            let holds = when
                .condition
                .iter()
                .all(|l| Self::literal_truth(l, bind, world).0);
            if holds {
                effects.extend(&when.effects);
            }
        }
        effects
    }

    /// Applies `action(args)` to `world`: `Err` names the failing
    /// precondition or undefined cost fluent.
    pub(crate) fn apply(
        &self,
        action: &Action,
        args: &[Name],
        world: &World,
    ) -> Result<(World, u64), StepFailure> {
        let bind = binding(action, args);
        for literal in &action.precondition {
            Self::literal_holds(literal, &bind, world).map_err(StepFailure::Precondition)?;
        }
        let one_disjunct_holds = action.alternatives.iter().any(|disjunct| {
            disjunct
                .iter()
                .all(|l| Self::literal_holds(l, &bind, world).is_ok())
        });
        if !action.alternatives.is_empty() && !one_disjunct_holds {
            return Err(StepFailure::Precondition(Self::disjunction_text(
                &action.alternatives,
                &bind,
                world,
            )));
        }
        let action_costs = crate::task::priced_by_effects(self.domain, self.problem);
        let mut cost = if action_costs { 0u64 } else { 1 };
        let mut next = world.clone();
        let mut adds = Vec::new();
        for effect in Self::effects_in(action, &bind, world) {
            match effect {
                Effect::Del(atom) => {
                    let args = atom.args.iter().map(|t| Self::ground(t, &bind)).collect();
                    next.remove(&(atom.predicate.clone(), args));
                }
                Effect::Add(atom) => {
                    let args = atom.args.iter().map(|t| Self::ground(t, &bind)).collect();
                    adds.push((atom.predicate.clone(), args));
                }
                Effect::IncreaseCost(amount, _) if action_costs => {
                    let n = match amount {
                        NumExpr::Number(n) => *n,
                        NumExpr::Function(call) => {
                            let args: Vec<Name> =
                                call.args.iter().map(|t| Self::ground(t, &bind)).collect();
                            let text = write_fact(&call.name, &args);
                            *self
                                .fluents
                                .get(&(call.name.clone(), args))
                                .ok_or(StepFailure::UndefinedCost(text))?
                        }
                    };
                    cost = cost.saturating_add(n);
                }
                Effect::IncreaseCost(..) => {}
            }
        }
        // Deletes first, then adds: an atom both deleted and added holds.
        next.extend(adds);
        Ok((next, cost))
    }

    /// The goal literals that fail in `world`.
    pub(crate) fn unmet_goals(&self, world: &World) -> Vec<String> {
        let bind = HashMap::new();
        self.problem
            .goal
            .iter()
            .filter_map(|l| Self::literal_holds(l, &bind, world).err())
            .collect()
    }
}

/// Why one step cannot be applied.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum StepFailure {
    Precondition(String),
    UndefinedCost(String),
}

/// Checks `plan` (ground calls such as `(move astrid living-room entrance)`)
/// against `domain` and `problem`: every step is a known action applied to
/// objects of the right types, its preconditions hold when it is applied, and
/// the goal holds at the end. Returns the plan's cost.
pub fn validate(domain: &Domain, problem: &Problem, plan: &[Call]) -> Result<u64, PlanError> {
    let semantics = Semantics::new(domain, problem);
    let mut world = semantics.initial();
    let mut total = 0u64;
    for (i, call) in plan.iter().enumerate() {
        let step = i + 1;
        let Some(action) = domain.actions.iter().find(|a| a.name == call.name) else {
            return Err(PlanError::UnknownAction {
                step,
                action: call.name.to_string(),
            });
        };
        if action.params.len() != call.args.len() {
            return Err(PlanError::Arity {
                step,
                action: call.name.to_string(),
                expected: action.params.len(),
                given: call.args.len(),
            });
        }
        let mut args = Vec::new();
        for (param, arg) in action.params.iter().zip(&call.args) {
            let ty = param.ty.as_deref().unwrap_or("object");
            let name = match arg {
                Term::Const(c) if semantics.has_type(c, ty) => c.clone(),
                Term::Const(c) | Term::Var(c) => {
                    return Err(PlanError::BadArgument {
                        step,
                        arg: c.to_string(),
                        ty: ty.to_string(),
                    });
                }
            };
            args.push(name);
        }
        match semantics.apply(action, &args, &world) {
            Ok((next, cost)) => {
                world = next;
                total = total.saturating_add(cost);
            }
            Err(StepFailure::Precondition(literal)) => {
                return Err(PlanError::Precondition {
                    step,
                    call: call.to_string(),
                    literal,
                });
            }
            Err(StepFailure::UndefinedCost(function)) => {
                return Err(PlanError::UndefinedCost {
                    step,
                    call: call.to_string(),
                    function,
                });
            }
        }
    }
    let unmet = semantics.unmet_goals(&world);
    if unmet.is_empty() {
        Ok(total)
    } else {
        Err(PlanError::GoalNotReached { literals: unmet })
    }
}
