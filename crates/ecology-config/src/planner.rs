//! The planning driver: a [`Search`] prepared from a request (the state
//! compiled against the domain's schemas, the goal grounded, the provider
//! search built when the domain has provider shape), run in slices under the
//! caller's budget and finished into an [`Outcome`].

use std::fmt;
use std::sync::Arc;
use std::time::Duration;

use ecology_core::Clock;
use ecology_domain::{Call, Domain};

use crate::compile::{self, Callee, Compiled, Schema};
use crate::cost::CostModel;
use crate::explain;
use crate::ground::{self, Ctx, Excluded};
use crate::model::{Exclusion, Options, Outcome, Request, RequestError, Snapshot, Stats, Status};
use crate::relaxed::Relaxed;
use crate::search::Engine;
use crate::share;

/// A search that can be run in steps under an outside budget.
pub struct Search<'a> {
    /// The tree search, and the ground graph both searches read. Seen by the
    /// crate's tests, which check which search ran.
    pub(crate) engine: Engine<'a>,
    /// The search over chosen providers, when the domain has provider shape.
    pub(crate) shared: Option<share::Shared>,
    count: usize,
    explain: bool,
    dived: bool,
}

impl fmt::Debug for Search<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Search")
            .field("count", &self.count)
            .field("expanded", &self.engine.expanded)
            .finish_non_exhaustive()
    }
}

/// What one call of [`Search::step`] reached.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    /// More work remains.
    InProgress,
    /// The search is over; [`Search::finish`] has the proven result.
    Done,
}

impl<'a> Search<'a> {
    /// Prepares a search: compiles the domain and state, grounds the goal.
    pub fn new(
        request: &Request<'a>,
        cost_model: &'a dyn CostModel,
        options: &Options,
    ) -> Result<Search<'a>, RequestError> {
        let (Prepared { schema, .. }, goal) = prepared_and_goal(request, None)?;
        Ok(Search::new_until(
            request,
            schema,
            goal,
            cost_model,
            options,
            &|| false,
        ))
    }

    /// Like [`Search::new`], asking `over` between phases and now and then
    /// while grounding whether the budget ran out; if it did, the search is
    /// [`Search::cut`] and finishes at once with nothing and no bound.
    /// `schema` is the request's domain compiled, `goal` its goal checked
    /// against it ([`check_goal`]).
    fn new_until(
        request: &Request<'a>,
        schema: Arc<Schema>,
        (callee, goal_args): Goal<'_>,
        cost_model: &'a dyn CostModel,
        options: &Options,
        over: &dyn Fn() -> bool,
    ) -> Search<'a> {
        let mut compiled = Compiled::new_until(schema, request.state, over);
        let args: Vec<compile::Sym> = goal_args
            .iter()
            .map(|a| compiled.syms.intern_str(a))
            .collect();
        let excluded = excluded(&mut compiled, request.exclusions);
        let cut = compiled.cut || over();
        let ctx = Ctx::new(request.domain, compiled, cost_model, excluded, callee);
        let mut engine = Engine::new(ctx, callee, &args, cut, options.count <= 1, &|| over());
        let shared = if engine.graph.cut || over() {
            engine.graph.cut = true;
            None
        } else if engine.graph.item(engine.root).lb == ground::INFEASIBLE {
            // Nothing can be provided (an information without a provider that
            // is not excluded, say): proven at once, without building the
            // search; the tree search finishes with the explanation.
            None
        } else {
            match share::Shared::new(&engine, options.count, over) {
                Ok(shared) => shared,
                Err(share::Cut) => {
                    engine.graph.cut = true;
                    None
                }
            }
        };
        Search {
            engine,
            shared,
            count: options.count.max(1),
            explain: options.explain,
            dived: false,
        }
    }

    /// Runs at most `expansions` steps.
    pub fn step(&mut self, expansions: u64) -> Progress {
        self.step_until(expansions, &|| false)
    }

    /// Like [`Search::step`], asking `over` now and then during the provider
    /// search's dives (which may wire a whole configuration in one step)
    /// whether the budget ran out; if so, returns early.
    fn step_until(&mut self, expansions: u64, over: &dyn Fn() -> bool) -> Progress {
        if let Some(shared) = &mut self.shared {
            return if shared.step(expansions, over) {
                Progress::Done
            } else {
                Progress::InProgress
            };
        }
        if !self.dived && self.count == 1 {
            self.dived = true;
            self.engine.dive(expansions.max(1));
        }
        for _ in 0..expansions {
            if self.engine.accepted.len() >= self.count || self.engine.is_exhausted() {
                return Progress::Done;
            }
            self.engine.step(self.count == 1);
        }
        if self.engine.accepted.len() >= self.count || self.engine.is_exhausted() {
            Progress::Done
        } else {
            Progress::InProgress
        }
    }

    /// Nodes expanded so far.
    pub fn expanded(&self) -> u64 {
        match &self.shared {
            Some(shared) => shared.expanded,
            None => self.engine.expanded,
        }
    }

    /// Whether preparing the search was cut short by the budget: it has
    /// nothing to search, and its bound means nothing.
    fn cut(&self) -> bool {
        self.engine.graph.cut
    }

    /// Where the search stands.
    pub fn snapshot(&self) -> Snapshot {
        Snapshot {
            expanded: self.expanded(),
            best: self.best(),
            lower_bound: match &self.shared {
                Some(shared) => shared.lower_bound(),
                None => self.engine.lower_bound(),
            },
        }
    }

    /// The cost of the cheapest configuration found so far.
    fn best(&self) -> Option<u64> {
        match &self.shared {
            Some(shared) => shared.best(),
            None => {
                let engine = &self.engine;
                let best = engine.accepted.first().or(engine.incumbent.as_ref());
                best.map(|c| c.cost)
            }
        }
    }

    /// Whether a configuration has been found (not necessarily the best).
    pub fn found(&self) -> bool {
        self.best().is_some()
    }

    /// Ends the search. With `complete` false (the budget ran out), returns
    /// the best found so far, not proven.
    pub fn finish(self, complete: bool, elapsed: Duration) -> Outcome {
        self.finish_until(complete, elapsed, &|| false)
    }

    /// Like [`Search::finish`], asking `over` between the configurations it
    /// builds whether the budget ran out; if so, the list is cut short (the
    /// ones built are still the cheapest, but the outcome is not proven).
    fn finish_until(
        mut self,
        complete: bool,
        elapsed: Duration,
        over: &dyn Fn() -> bool,
    ) -> Outcome {
        if let Some(mut shared) = self.shared.take() {
            let lower_bound = if complete { None } else { shared.lower_bound() };
            let (configurations, explanation, whole) =
                shared.finish(&mut self.engine, complete, self.explain, over);
            let lower_bound = match (lower_bound, whole) {
                (None, false) => configurations.last().map(|c| c.cost),
                (bound, _) => bound,
            };
            return Outcome {
                configurations,
                status: Status::of(complete && whole),
                explanation,
                lower_bound,
                stats: Stats {
                    expanded: shared.expanded,
                    generated: shared.generated,
                    alternatives: self.engine.graph.alternatives,
                    micros: elapsed.as_micros() as u64,
                    first_micros: None,
                },
            };
        }
        let mut configurations = std::mem::take(&mut self.engine.accepted);
        let proven_count = configurations.len();
        if configurations.is_empty()
            && let Some(incumbent) = self.engine.incumbent.take()
        {
            configurations.push(incumbent);
        }
        for (i, c) in configurations.iter_mut().enumerate() {
            c.optimal = complete || i < proven_count;
        }
        let explanation = (configurations.is_empty() && complete && self.explain).then(|| {
            explain::explain(
                &self.engine.ctx,
                &self.engine.graph,
                self.engine.root,
                &self.engine.rejections,
            )
        });
        Outcome {
            configurations,
            status: Status::of(complete),
            explanation,
            lower_bound: if complete {
                None
            } else {
                self.engine.lower_bound()
            },
            stats: Stats {
                expanded: self.engine.expanded,
                generated: self.engine.generated,
                alternatives: self.engine.graph.alternatives,
                micros: elapsed.as_micros() as u64,
                first_micros: None,
            },
        }
    }
}

/// A domain compiled for planning, once for many plans in a [`crate::Planner`]
/// or once per plan otherwise.
#[derive(Debug, Clone)]
pub(crate) struct Prepared {
    /// The schemas, shared with every plan's compiled state.
    pub(crate) schema: Arc<Schema>,
    /// The schemas as the relaxation that proves "none" reads them.
    pub(crate) relaxed: Arc<Relaxed>,
}

impl Prepared {
    /// Compiles `domain`.
    pub(crate) fn new(domain: &Domain) -> Prepared {
        let schema = Schema::new(domain);
        let relaxed = Relaxed::new(&schema);
        Prepared {
            schema: Arc::new(schema),
            relaxed: Arc::new(relaxed),
        }
    }
}

/// Plans `request`, with `prepared` its domain compiled already (when it
/// is `None`, the domain is compiled first), calling `observe` between steps.
pub(crate) fn plan_prepared<'a>(
    request: &Request<'a>,
    prepared: Option<&Prepared>,
    cost_model: &'a dyn CostModel,
    options: &Options,
    clock: &dyn Clock,
    observe: &mut dyn FnMut(Snapshot),
) -> Result<Outcome, RequestError> {
    const SLICE: u64 = 64;
    let over_time = || {
        options
            .budget
            .max_time
            .is_some_and(|t| clock.elapsed() >= t)
    };
    let (Prepared { schema, relaxed }, goal) = prepared_and_goal(request, prepared)?;
    if !options.explain
        && relaxed.proves_none(
            &schema,
            request.state,
            goal.0,
            &goal.1,
            request.exclusions,
            &over_time,
        )
    {
        return Ok(Outcome {
            configurations: Vec::new(),
            status: Status::Proven,
            explanation: None,
            lower_bound: None,
            stats: Stats {
                micros: clock.elapsed().as_micros() as u64,
                ..Stats::default()
            },
        });
    }
    let mut search = Search::new_until(request, schema, goal, cost_model, options, &over_time);
    if search.cut() {
        // The bound is the goal's when grounding was complete, else none.
        return Ok(search.finish(false, clock.elapsed()));
    }
    let mut first = None;
    let finish = |search: Search<'a>, complete: bool, first: Option<Duration>| {
        let mut outcome = search.finish_until(complete, Duration::ZERO, &over_time);
        outcome.stats.micros = clock.elapsed().as_micros() as u64;
        outcome.stats.first_micros = first
            .filter(|_| !outcome.configurations.is_empty())
            .map(|t: Duration| t.as_micros() as u64);
        outcome
    };
    // The provider search's first step is its greedy dive alone, one
    // expansion per input it wires: allow it a whole configuration.
    const DIVE: u64 = 1024;
    let mut started = false;
    loop {
        let cap = if !started && search.shared.is_some() {
            DIVE
        } else {
            SLICE
        };
        started = true;
        let slice = match options.budget.max_expansions {
            Some(max) => cap.min(max.saturating_sub(search.expanded())),
            None => cap,
        };
        if slice == 0 || over_time() {
            return Ok(finish(search, false, first));
        }
        let progress = search.step_until(slice, &over_time);
        if first.is_none() && search.found() {
            first = Some(clock.elapsed());
        }
        observe(search.snapshot());
        if progress == Progress::Done {
            return Ok(finish(search, true, first));
        }
    }
}

/// Maps exclusions onto interned symbols; unknown names exclude nothing.
fn excluded(compiled: &mut Compiled, exclusions: &[Exclusion]) -> Excluded {
    let mut out = Excluded::default();
    for e in exclusions {
        match e {
            Exclusion::Component { peis, component } => {
                let p = compiled.syms.intern_str(peis);
                let c = compiled.syms.intern_str(component);
                out.components.insert((p, c));
            }
            Exclusion::Peis(peis) => {
                let p = compiled.syms.intern_str(peis);
                out.peis.insert(p);
            }
        }
    }
    out
}

/// A goal checked against its domain: its callee and arguments.
type Goal<'g> = (Callee, Vec<&'g str>);

/// The request's domain compiled (`prepared`, when given, is it already),
/// and its goal checked against it.
pub(crate) fn prepared_and_goal<'g>(
    request: &Request<'g>,
    prepared: Option<&Prepared>,
) -> Result<(Prepared, Goal<'g>), RequestError> {
    let prepared = match prepared {
        Some(prepared) => prepared.clone(),
        None => Prepared::new(request.domain),
    };
    let goal = check_goal(request.domain, &prepared.schema, request.goal)?;
    Ok((prepared, goal))
}

/// The goal's callee and arguments, checked against the domain.
fn check_goal<'g>(
    domain: &Domain,
    schema: &Schema,
    goal: &'g Call,
) -> Result<Goal<'g>, RequestError> {
    let Some(&callee) = schema.callee_by_name.get(&goal.name) else {
        return Err(RequestError::UnknownGoal {
            name: goal.name.to_string(),
        });
    };
    let expected = match callee {
        Callee::Func(f) => domain.functionalities[schema.funcs[f as usize].src]
            .params
            .len(),
        Callee::Task(t) => domain.tasks[schema.tasks[t as usize].src].params.len(),
    };
    if expected != goal.args.len() {
        return Err(RequestError::Arity {
            name: goal.name.to_string(),
            expected,
            given: goal.args.len(),
        });
    }
    let mut args = Vec::new();
    for t in &goal.args {
        match t {
            ecology_domain::Term::Const(c) => args.push(&**c),
            ecology_domain::Term::Var(v) => return Err(RequestError::NotGround(format!("?{v}"))),
        }
    }
    Ok((callee, args))
}
