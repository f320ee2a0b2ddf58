//! The configuration planner of Ecology (the paper's Section V).
//!
//! Given a [`Domain`], an [`EcologyState`] and a goal such as
//! `(navigate astrid bedroom)`, it finds the cheapest *admissible*
//! configuration: functionality instances on PEIS-components and the channels
//! between them, such that every precondition holds in the state and every
//! input is connected to a compatible output at a sufficient rate. It can
//! also list admissible configurations cheapest first, and when none exists it
//! says why with an [`Explanation`].
//!
//! The planner is sans-IO: time comes from a [`Clock`] the caller passes in.
//!
//! ```
//! use ecology_config::{plan, Options, Request, Status};
//! let domain = ecology_domain::parse_domain(br#"(define (domain d)
//!   (:functionality cam :parameters (?p ?c) :component (?p ?c)
//!     :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 5)
//!   (:task see :parameters (?p))
//!   (:method see-with-camera :parameters (?p ?c) :task (see ?p)
//!     :precondition (pc ?p cam ?c) :subtasks ((f1 (cam ?p ?c)))))"#).unwrap();
//! let state = ecology_domain::parse_facts(b"(pc robot cam c1) (cost robot c1 3 on)").unwrap();
//! let goal = ecology_domain::parse_goal("(see robot)").unwrap();
//! let request = Request { domain: &domain, state: &state, goal: &goal, exclusions: &[] };
//! let outcome = plan(&request, &Options::default(), &ecology_config::NoClock).unwrap();
//! assert_eq!(outcome.status, Status::Proven);
//! assert_eq!(outcome.configurations[0].cost, 3);
//! ```

mod compile;
mod cost;
mod explain;
mod ground;
mod model;
pub mod oracle;
mod planner;
mod relaxed;
mod relevant;
mod search;
mod share;
pub mod synthetic;

#[cfg(test)]
mod tests;

use ecology_domain::{Domain, EcologyState};

pub use cost::{CostModel, PaperCost};
/// The budget and the caller's clock live in `ecology-core`, shared with the action planner.
pub use ecology_core::{Budget, Clock, NoClock, WallClock};
pub use explain::Explanation;
pub use model::{
    ChannelInstance, Configuration, Exclusion, FunctionalityInstance, Options, Outcome, Request,
    RequestError, Snapshot, Stats, Status,
};
pub use planner::{Progress, Search};
pub use relevant::{Scope, component_scope, component_types};

use planner::{Prepared, plan_prepared};

/// The planner's first step alone, for the benchmark of reading a state: every name of the
/// state interned and its facts indexed for the domain's preconditions. Returns the number of
/// symbols.
#[doc(hidden)]
pub fn compile_state(domain: &Domain, state: &EcologyState) -> usize {
    let schema = std::sync::Arc::new(compile::Schema::new(domain));
    compile::Compiled::new_until(schema, state, &|| false)
        .syms
        .len()
}

/// Plans with the paper's cost model; see [`plan_with`].
pub fn plan<'a>(
    request: &Request<'a>,
    options: &Options,
    clock: &dyn Clock,
) -> Result<Outcome, RequestError> {
    plan_with(request, &PaperCost, options, clock)
}

/// Finds the cheapest admissible configuration (or the `options.count`
/// cheapest), stopping early when the budget runs out. Compiles the domain
/// first; to plan many times with one domain, see [`Planner`].
pub fn plan_with<'a>(
    request: &Request<'a>,
    cost_model: &'a dyn CostModel,
    options: &Options,
    clock: &dyn Clock,
) -> Result<Outcome, RequestError> {
    plan_prepared(request, None, cost_model, options, clock, &mut |_| {})
}

/// As [`plan_with`], calling `observe` between steps of the search (every
/// few dozen expansions) with where it stands: a caller can show the
/// progress of a long search.
pub fn plan_observed<'a>(
    request: &Request<'a>,
    cost_model: &'a dyn CostModel,
    options: &Options,
    clock: &dyn Clock,
    observe: &mut dyn FnMut(Snapshot),
) -> Result<Outcome, RequestError> {
    plan_prepared(request, None, cost_model, options, clock, observe)
}

/// A domain compiled once, to plan with it again and again: the executive
/// plans every action of a task with one domain and a new state. A plan
/// through it does the work of [`plan`] less compiling the domain's schemas;
/// the results are the same.
///
/// ```
/// use ecology_config::{NoClock, Options, Planner, Request};
/// let domain = ecology_domain::parse_domain(br#"(define (domain d)
///   (:functionality cam :parameters (?p ?c) :component (?p ?c)
///     :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 5)
///   (:task see :parameters (?p))
///   (:method see-with-camera :parameters (?p ?c) :task (see ?p)
///     :precondition (pc ?p cam ?c) :subtasks ((f1 (cam ?p ?c)))))"#).unwrap();
/// let goal = ecology_domain::parse_goal("(see robot)").unwrap();
/// let planner = Planner::new(domain);
/// // One state, then the next: the domain is compiled once.
/// for (facts, cost) in [("(pc robot cam c1) (cost robot c1 3 on)", 3),
///                       ("(pc robot cam c2) (cost robot c2 2 on)", 2)] {
///     let state = ecology_domain::parse_facts(facts.as_bytes()).unwrap();
///     let request = Request { domain: planner.domain(), state: &state, goal: &goal, exclusions: &[] };
///     let outcome = planner.plan(&request, &Options::default(), &NoClock).unwrap();
///     assert_eq!(outcome.configurations[0].cost, cost);
/// }
/// ```
#[derive(Debug, Clone)]
pub struct Planner {
    domain: Domain,
    prepared: Prepared,
}

impl Planner {
    /// Compiles `domain`, and keeps it.
    pub fn new(domain: Domain) -> Planner {
        let prepared = Prepared::new(&domain);
        Planner { domain, prepared }
    }

    /// The domain it plans with.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// The world a configuration for `action` (an action of the domain written `(move astrid
    /// living-room entrance)`) is planned in: the ground atoms of its precondition whose
    /// predicates a functionality or method of the domain reads (the predicates the compiled
    /// domain indexes). The action planner started the action where its precondition holds, so
    /// they hold when it starts; a method can ask where the robot is (`(at ?r ?x)`). Empty for an
    /// action the domain does not know, or written otherwise.
    pub fn facts_at_action(&self, action: &str) -> Vec<ecology_domain::Fact> {
        let schema = &self.prepared.schema;
        relevant::facts_at_action(&self.domain, action, |p| schema.reads(p))
    }

    /// The domain compiled, when `domain` is this planner's own
    /// ([`Planner::domain`]). An equal copy is not recognised: telling would
    /// cost a comparison of whole domains on every plan.
    fn prepared_for(&self, domain: &Domain) -> Option<&Prepared> {
        std::ptr::eq(domain, &self.domain).then_some(&self.prepared)
    }

    /// Plans with the paper's cost model; see [`Planner::plan_with`].
    pub fn plan(
        &self,
        request: &Request<'_>,
        options: &Options,
        clock: &dyn Clock,
    ) -> Result<Outcome, RequestError> {
        plan_prepared(
            request,
            self.prepared_for(request.domain),
            &PaperCost,
            options,
            clock,
            &mut |_| {},
        )
    }

    /// As [`plan_with`], with the domain compiled already: the request's
    /// `domain` must be [`Planner::domain`] for that. A request with any
    /// other domain (an equal copy too) is planned as [`plan_with`] plans
    /// it, compiling that domain.
    pub fn plan_with<'a>(
        &self,
        request: &Request<'a>,
        cost_model: &'a dyn CostModel,
        options: &Options,
        clock: &dyn Clock,
    ) -> Result<Outcome, RequestError> {
        plan_prepared(
            request,
            self.prepared_for(request.domain),
            cost_model,
            options,
            clock,
            &mut |_| {},
        )
    }
}
