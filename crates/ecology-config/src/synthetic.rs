//! Seeded generators of synthetic ecologies, for property tests and benchmarks.
//!
//! Each generator writes a domain and a state as `.eco` and `.facts` text and
//! parses them back, so the parser is exercised too. Randomness comes from a
//! small seeded generator: the same seed gives the same ecology everywhere.

use std::fmt::Write;

use ecology_domain::{Call, Domain, EcologyState};

use crate::model::{Exclusion, Request};

/// The seeded generator (SplitMix64), shared with the simulation.
pub use ecology_core::Rng;

/// A generated problem, as text and parsed.
#[derive(Debug, Clone)]
pub struct Instance {
    /// The domain's source.
    pub domain_text: String,
    /// The state's source.
    pub facts_text: String,
    /// The goal's source.
    pub goal_text: String,
    /// The parsed domain.
    pub domain: Domain,
    /// The parsed state.
    pub state: EcologyState,
    /// The parsed goal.
    pub goal: Call,
    /// Every component, as `(peis, component)`.
    pub components: Vec<(String, String)>,
    /// Components that have failed: plan with these excluded.
    pub exclusions: Vec<Exclusion>,
}

impl Instance {
    /// The request for this instance: its goal, with its failed components excluded.
    pub fn request(&self) -> Request<'_> {
        Request {
            domain: &self.domain,
            state: &self.state,
            goal: &self.goal,
            exclusions: &self.exclusions,
        }
    }
}

/// Why a generated instance did not parse: a generator bug, with the text.
#[derive(Debug, Clone)]
pub struct GeneratorError(pub String);

fn finish(
    domain_text: String,
    facts_text: String,
    goal_text: String,
    components: Vec<(String, String)>,
) -> Result<Instance, GeneratorError> {
    let domain = ecology_domain::parse_domain(domain_text.as_bytes())
        .map_err(|d| GeneratorError(d.render("generated.eco", domain_text.as_bytes())))?;
    let state = ecology_domain::parse_facts(facts_text.as_bytes())
        .map_err(|d| GeneratorError(d.render("generated.facts", facts_text.as_bytes())))?;
    let goal = ecology_domain::parse_goal(&goal_text)
        .map_err(|d| GeneratorError(d.render("goal", goal_text.as_bytes())))?;
    Ok(Instance {
        domain_text,
        facts_text,
        goal_text,
        domain,
        state,
        goal,
        components,
        exclusions: Vec::new(),
    })
}

/// A diamond of `depth` levels on one robot: at each level one component
/// provides both information types that the level above needs, so the
/// decomposition of the goal `(ga0)` doubles with each level while its
/// configuration has one component per level. With `side`, each method also
/// runs a functionality of its own on a second component, so the domain is
/// not of provider shape and the decomposition tree search plans it; listing
/// its configurations searches every occurrence of a shared provider again,
/// which doubles with each level.
pub fn diamond(depth: usize, side: bool) -> Result<Instance, GeneratorError> {
    let mut domain = String::from("(define (domain diamond)\n");
    let mut facts = String::new();
    let mut components = Vec::new();
    for i in 0..=depth {
        let (input, mut subtasks, channels) = if i < depth {
            let j = i + 1;
            (
                format!("(a{j}) (b{j})"),
                format!(" (s1 (ga{j})) (s2 (gb{j}))"),
                format!(" :channels ((s1 s0 (a{j})) (s2 s0 (b{j})))"),
            )
        } else {
            Default::default()
        };
        let mut pre = format!("(sig ?p ?c s{i})");
        let _ = writeln!(
            domain,
            "(:functionality h{i} :parameters (?p ?c) :component (?p ?c) \
             :precondition {pre} :input ({input}) :output ((a{i}) (b{i})) :cost 1)"
        );
        let _ = writeln!(facts, "(sig robot c{i} s{i})");
        components.push(("robot".to_string(), format!("c{i}")));
        if side {
            let _ = writeln!(
                domain,
                "(:functionality k{i} :parameters (?p ?e) :component (?p ?e) \
                 :precondition (mon ?p ?e s{i}) :input () :output () :cost 1)"
            );
            let _ = writeln!(facts, "(mon robot e{i} s{i})");
            components.push(("robot".to_string(), format!("e{i}")));
            let _ = write!(subtasks, " (s3 (k{i} ?p ?e))");
            pre = format!("(and {pre} (mon ?p ?e s{i}))");
        }
        for x in ["a", "b"] {
            let _ = writeln!(
                domain,
                "(:task g{x}{i} :parameters () :output (({x}{i})))\n\
                 (:method g{x}{i}-by-h :parameters (?p ?c ?e) :task (g{x}{i}) \
                 :precondition {pre} :subtasks ((s0 (h{i} ?p ?c)){subtasks}){channels} \
                 :outputs ((({x}{i}) s0)))"
            );
        }
    }
    domain.push(')');
    finish(domain, facts, "(ga0)".to_string(), components)
}

/// A small random ecology for testing against the brute-force oracle: one to
/// three PEIS, a handful of component types and functionalities, three layers
/// of tasks with one to three methods each, random channels, rates, sharing
/// and clashes.
pub fn small(seed: u64) -> Result<Instance, GeneratorError> {
    let mut rng = Rng::new(seed);
    let n_peis = 1 + rng.below(3);
    let n_types = 2 + rng.below(3);
    let n_infos = 1 + rng.below(3);
    let mut facts = String::new();
    let mut components = Vec::new();
    for p in 0..n_peis {
        writeln!(facts, "(peis p{p})").ok();
        if rng.chance(0.7) {
            writeln!(facts, "(ok p{p})").ok();
        }
        for t in 0..n_types {
            for k in 0..2 {
                if rng.chance(if k == 0 { 0.6 } else { 0.2 }) {
                    let c = format!("c{p}{t}{k}");
                    writeln!(facts, "(pc p{p} t{t} {c})").ok();
                    if rng.chance(0.8) {
                        let power = if rng.chance(0.5) { "on" } else { "off" };
                        writeln!(facts, "(cost p{p} {c} {} {power})", rng.below(40)).ok();
                    }
                    components.push((format!("p{p}"), c));
                }
            }
        }
    }
    if n_peis > 1 && rng.chance(0.3) {
        writeln!(facts, "(channel-cost p0 p1 {})", rng.below(10)).ok();
    }
    // Functionalities.
    struct F {
        ty: u64,
        inputs: Vec<u64>,
        outputs: Vec<u64>,
    }
    let mut domain = String::from("(define (domain small)\n");
    let n_funcs = 2 + rng.below(4);
    let mut funcs = Vec::new();
    for f in 0..n_funcs {
        let ty = rng.below(n_types);
        let inputs: Vec<u64> = (0..n_infos).filter(|_| rng.chance(0.25)).collect();
        let outputs: Vec<u64> = (0..n_infos).filter(|_| rng.chance(0.5)).collect();
        let hz = |rng: &mut Rng| {
            if rng.chance(0.2) {
                format!(" :hz {}", 1 + rng.below(3) * 10)
            } else {
                String::new()
            }
        };
        let ins: String = inputs
            .iter()
            .map(|i| format!("(i{i}{})", hz(&mut rng)))
            .collect();
        let outs: String = outputs
            .iter()
            .map(|i| format!("(i{i}{})", hz(&mut rng)))
            .collect();
        let ok = if rng.chance(0.2) { " (ok ?p)" } else { "" };
        writeln!(
            domain,
            "  (:functionality f{f} :parameters (?p ?c) :component (?p ?c)\n    :precondition (and (pc ?p t{ty} ?c){ok}) :input ({ins}) :output ({outs}) :cost {})",
            rng.below(30)
        )
        .ok();
        funcs.push(F {
            ty,
            inputs,
            outputs,
        });
    }
    // Tasks, bottom-up so that their interfaces are known to the layers above.
    let mut task_outputs: Vec<Vec<u64>> = Vec::new();
    let mut task_inputs: Vec<Vec<u64>> = Vec::new();
    for level in (0..3u64).rev() {
        writeln!(domain, "  (:task t{level} :parameters ())").ok();
        let mut outs_union: Vec<u64> = Vec::new();
        let mut ins_union: Vec<u64> = Vec::new();
        for m in 0..1 + rng.below(3) {
            // Subtasks: functionalities, or tasks of lower levels (already declared).
            let n_sub = 1 + rng.below(3);
            let mut subs: Vec<(String, Vec<u64>, Vec<u64>)> = Vec::new(); // call, inputs, outputs
            let mut pre = Vec::new();
            let mut bound: Vec<u64> = Vec::new();
            let mut first_is_func = false;
            for j in 0..n_sub {
                let lower_tasks = 2 - level; // tasks t{level+1}..t2 exist
                if lower_tasks > 0 && rng.chance(0.35) {
                    let t = level + 1 + rng.below(lower_tasks);
                    let idx = (2 - t) as usize;
                    subs.push((
                        format!("(t{t})"),
                        task_inputs[idx].clone(),
                        task_outputs[idx].clone(),
                    ));
                } else {
                    let f = rng.below(n_funcs) as usize;
                    // Usually the functionality's own type; sometimes another (then
                    // the functionality's precondition fails), sometimes shared vars.
                    let ty = if rng.chance(0.85) {
                        funcs[f].ty
                    } else {
                        rng.below(n_types)
                    };
                    // Reusing the first subtask's variables makes two subtasks
                    // share (or clash on) one component.
                    let var = if j > 0 && first_is_func && rng.chance(0.15) {
                        0
                    } else {
                        j
                    };
                    if j == 0 {
                        first_is_func = true;
                    }
                    if var == j {
                        pre.push(format!("(pc ?p{j} t{ty} ?c{j})"));
                        bound.push(j);
                    }
                    subs.push((
                        format!("(f{f} ?p{var} ?c{var})"),
                        funcs[f].inputs.clone(),
                        funcs[f].outputs.clone(),
                    ));
                }
            }
            if bound.len() >= 2 && rng.chance(0.3) {
                pre.push(format!("(not (= ?p{} ?p{}))", bound[0], bound[1]));
            }
            let mut channels = String::new();
            let mut fed: Vec<(usize, u64)> = Vec::new();
            for a in 0..subs.len() {
                for b in 0..subs.len() {
                    if a == b {
                        continue;
                    }
                    for &i in &subs[a].2 {
                        if subs[b].1.contains(&i) && rng.chance(0.7) {
                            write!(channels, "(s{a} s{b} (i{i}))").ok();
                            fed.push((b, i));
                        }
                    }
                }
            }
            let mut outputs = String::new();
            for i in 0..n_infos {
                let providers: Vec<usize> = (0..subs.len())
                    .filter(|&s| subs[s].2.contains(&i))
                    .collect();
                if !providers.is_empty() && rng.chance(0.6) {
                    let s = providers[rng.below(providers.len() as u64) as usize];
                    write!(outputs, "((i{i}) s{s})").ok();
                    outs_union.push(i);
                }
            }
            let mut inputs = String::new();
            for (s, sub) in subs.iter().enumerate() {
                for &i in &sub.1 {
                    if !fed.contains(&(s, i)) && rng.chance(0.5) {
                        write!(inputs, "((i{i}) s{s})").ok();
                        ins_union.push(i);
                    }
                }
            }
            let vars: String = (0..n_sub).map(|j| format!(" ?p{j} ?c{j}")).collect();
            let subtasks: String = subs
                .iter()
                .enumerate()
                .map(|(s, sub)| format!("(s{s} {})", sub.0))
                .collect();
            writeln!(
                domain,
                "  (:method t{level}-m{m} :parameters ({}) :task (t{level})\n    :precondition (and {}) :subtasks ({subtasks})\n    :channels ({channels}) :inputs ({inputs}) :outputs ({outputs}))",
                vars.trim(),
                pre.join(" ")
            )
            .ok();
        }
        outs_union.sort_unstable();
        outs_union.dedup();
        ins_union.sort_unstable();
        ins_union.dedup();
        task_outputs.push(outs_union);
        task_inputs.push(ins_union);
    }
    domain.push(')');
    let goal = if rng.chance(0.9) {
        "(t0)".to_string()
    } else {
        "(t1)".to_string()
    };
    finish(domain, facts, goal, components)
}

/// Parameters of a benchmark ecology.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shape {
    /// PEIS in the ecology.
    pub peis: usize,
    /// Components on each PEIS.
    pub components_per_peis: usize,
    /// Component types.
    pub types: usize,
    /// Alternative methods per task.
    pub methods: usize,
    /// Levels of task decomposition.
    pub depth: usize,
    /// Random seed.
    pub seed: u64,
}

/// A benchmark ecology shaped like the paper's: a robot `q0` needs information
/// produced through `depth` levels of tasks; each level's task has `methods`
/// alternatives, each binding a provider PEIS that has two component types
/// (a source and a processor, like ceiling cameras and a tracking system), fed
/// by the level below. Costs and on/off states are random.
pub fn ecology(shape: Shape) -> Result<Instance, GeneratorError> {
    let mut rng = Rng::new(shape.seed);
    let types = shape.types.max(2) as u64;
    let mut facts = String::with_capacity(shape.peis * shape.components_per_peis * 48);
    let mut components = Vec::new();
    for p in 0..shape.peis {
        writeln!(facts, "(peis q{p})").ok();
        for k in 0..shape.components_per_peis {
            let c = format!("c{p}x{k}");
            let t = rng.below(types);
            let power = if rng.chance(0.5) { "on" } else { "off" };
            writeln!(
                facts,
                "(pc q{p} t{t} {c}) (cost q{p} {c} {} {power})",
                1 + rng.below(100)
            )
            .ok();
            components.push((format!("q{p}"), c));
        }
    }
    let mut domain = String::from("(define (domain synthetic)\n");
    for d in 0..shape.depth {
        writeln!(
            domain,
            "  (:task level{d} :parameters (?r) :output ((info{d} ?r)))"
        )
        .ok();
        for j in 0..shape.methods {
            let source = rng.below(types);
            let processor = rng.below(types);
            let below = d + 1 < shape.depth;
            let input = if below {
                format!(" :input ((info{} ?r))", d + 1)
            } else {
                String::new()
            };
            writeln!(
                domain,
                "  (:functionality source{d}-{j} :parameters (?r ?p ?c) :component (?p ?c)\n    :precondition (pc ?p t{source} ?c){input} :output ((mid{d}-{j} ?r)) :cost {})",
                rng.below(50)
            )
            .ok();
            writeln!(
                domain,
                "  (:functionality process{d}-{j} :parameters (?r ?p ?c) :component (?p ?c)\n    :precondition (pc ?p t{processor} ?c) :input ((mid{d}-{j} ?r)) :output ((info{d} ?r)) :cost {})",
                rng.below(50)
            )
            .ok();
            let (lower, lower_channel) = if below {
                (
                    format!("(s0 (level{} ?r)) ", d + 1),
                    format!("(s0 s1 (info{} ?r)) ", d + 1),
                )
            } else {
                (String::new(), String::new())
            };
            writeln!(
                domain,
                "  (:method level{d}-by-{j} :parameters (?r ?p ?c1 ?c2) :task (level{d} ?r)\n    :precondition (and (peis ?r) (pc ?p t{source} ?c1) (pc ?p t{processor} ?c2) (not (= ?c1 ?c2)))\n    :subtasks ({lower}(s1 (source{d}-{j} ?r ?p ?c1)) (s2 (process{d}-{j} ?r ?p ?c2)))\n    :channels ({lower_channel}(s1 s2 (mid{d}-{j} ?r)))\n    :outputs (((info{d} ?r) s2)))"
            )
            .ok();
        }
    }
    domain.push(')');
    finish(domain, facts, "(level0 q0)".to_string(), components)
}

/// Parameters of a shared-provider ecology (issue 11): providers serve several
/// consumers, and channels between PEIS cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sharing {
    /// PEIS in the ecology.
    pub peis: usize,
    /// Levels of information types below the goal (the goal type is level 0).
    pub levels: usize,
    /// Information types per level 1..=`levels`.
    pub types: usize,
    /// Components per PEIS and level.
    pub per_level: usize,
    /// Distinct types of the next level each component below the last needs.
    pub needs: usize,
    /// Fraction of components that have failed (excluded).
    pub failed: f64,
    /// Whether information comes at rates: each functionality offers its
    /// output at 10, 20 or 30 Hz and may ask as much of each input, so some
    /// providers are too slow for some consumers.
    pub rates: bool,
    /// Random seed.
    pub seed: u64,
}

impl Sharing {
    /// The base point: L=3, K=2, one component per level, R=2, none failed.
    pub fn base(peis: usize, seed: u64) -> Sharing {
        Sharing {
            peis,
            levels: 3,
            types: 2,
            per_level: 1,
            needs: 2,
            failed: 0.0,
            rates: false,
            seed,
        }
    }
}

/// An ecology where components are shared and channels cost (issue 11).
///
/// Every PEIS `q{p}` hosts, for each level `l` in `0..=levels`, `per_level`
/// components `c{l}x{j}`; each gets a type of its level (level 0 is the goal
/// type), a running cost in 1..=10 (on), and below the last level `needs`
/// distinct types of the next level. A channel from PEIS `a` to PEIS `b`
/// costs 1..=5. PEIS `q0` hosts a `user` component needing the goal type; the
/// goal `(serve)` feeds it. One functionality per (type, needs) signature, one
/// parameterless task `get-T` per type with one method per signature. The
/// instance's `exclusions` list the failed components.
pub fn sharing(shape: Sharing) -> Result<Instance, GeneratorError> {
    let mut rng = Rng::new(shape.seed);
    let levels = shape.levels.max(1);
    let k = shape.types.max(1);
    let r = shape.needs.clamp(1, k);
    let per = shape.per_level.max(1);
    let peis = shape.peis.max(1);
    let type_name = |l: usize, t: usize| {
        if l == 0 {
            "goal".to_string()
        } else {
            format!("ty{l}-{t}")
        }
    };
    let types_at = |l: usize| if l == 0 { 1 } else { k };
    // types[l][p * per + j]
    let mut types: Vec<Vec<usize>> = Vec::new();
    for l in 0..=levels {
        let n = types_at(l);
        let mut level: Vec<usize> = (0..peis * per)
            .map(|_| rng.below(n as u64) as usize)
            .collect();
        // Every type has a provider: give a missing one to a component whose
        // type has another provider.
        if level.len() >= n {
            loop {
                let mut count = vec![0usize; n];
                for &t in &level {
                    count[t] += 1;
                }
                let Some(missing) = count.iter().position(|&c| c == 0) else {
                    break;
                };
                let i = rng.below(level.len() as u64) as usize;
                if count[level[i]] > 1 {
                    level[i] = missing;
                }
            }
        }
        types.push(level);
    }
    let mut facts = String::with_capacity(peis * peis * 28 + peis * levels * 80);
    let mut components = Vec::new();
    let mut exclusions = Vec::new();
    let mut signatures: Vec<(usize, usize, Vec<usize>)> = Vec::new(); // level, type, needs
    for p in 0..peis {
        writeln!(facts, "(peis q{p})").ok();
        for (l, level) in types.iter().enumerate() {
            for j in 0..per {
                let c = format!("c{l}x{j}");
                let ty = level[p * per + j];
                let mut needs: Vec<usize> = Vec::new();
                if l < levels {
                    let mut pool: Vec<usize> = (0..k).collect();
                    for _ in 0..r {
                        let i = rng.below(pool.len() as u64) as usize;
                        needs.push(pool.swap_remove(i));
                    }
                    needs.sort_unstable();
                }
                let key = (l, ty, needs);
                let sig = match signatures.iter().position(|s| *s == key) {
                    Some(i) => i,
                    None => {
                        signatures.push(key);
                        signatures.len() - 1
                    }
                };
                writeln!(
                    facts,
                    "(sig q{p} {c} s{sig}) (cost q{p} {c} {} on)",
                    1 + rng.below(10)
                )
                .ok();
                if shape.failed > 0.0 && rng.chance(shape.failed) {
                    exclusions.push(Exclusion::Component {
                        peis: format!("q{p}"),
                        component: c.clone(),
                    });
                }
                components.push((format!("q{p}"), c));
            }
        }
    }
    writeln!(facts, "(user q0 u) (cost q0 u 0 on)").ok();
    components.push(("q0".to_string(), "u".to_string()));
    for a in 0..peis {
        for b in 0..peis {
            if a != b {
                writeln!(facts, "(channel-cost q{a} q{b} {})", 1 + rng.below(5)).ok();
            }
        }
    }
    let mut domain = String::from("(define (domain sharing)\n");
    // Rates from a stream of their own, so that the same seed gives the same
    // ecology with and without them.
    let mut rates = Rng::new(shape.seed ^ 0x05ee_d0f4_a7e5);
    let mut hz = |p: f64| {
        if shape.rates && rates.chance(p) {
            format!(" :hz {}", 10 * (1 + rates.below(3)))
        } else {
            String::new()
        }
    };
    writeln!(
        domain,
        "  (:functionality user :parameters (?p ?c) :component (?p ?c)\n    :precondition (user ?p ?c) :input ((goal{})) :cost 0)",
        hz(0.5)
    )
    .ok();
    for (s, (l, ty, needs)) in signatures.iter().enumerate() {
        let inputs: String = needs
            .iter()
            .map(|&n| format!("({}{})", type_name(l + 1, n), hz(0.5)))
            .collect();
        writeln!(
            domain,
            "  (:functionality f{s} :parameters (?p ?c) :component (?p ?c)\n    :precondition (sig ?p ?c s{s}) :input ({inputs}) :output (({}{})) :cost 0)",
            type_name(*l, *ty),
            hz(0.9)
        )
        .ok();
    }
    for l in 0..=levels {
        for t in 0..types_at(l) {
            let name = type_name(l, t);
            writeln!(
                domain,
                "  (:task get-{name} :parameters () :output (({name})))"
            )
            .ok();
            for (s, (sl, sty, needs)) in signatures.iter().enumerate() {
                if (*sl, *sty) != (l, t) {
                    continue;
                }
                let mut subtasks = format!("(s0 (f{s} ?p ?c))");
                let mut channels = String::new();
                for (i, &n) in needs.iter().enumerate() {
                    let need = type_name(l + 1, n);
                    write!(subtasks, " (s{} (get-{need}))", i + 1).ok();
                    write!(channels, "(s{} s0 ({need}))", i + 1).ok();
                }
                writeln!(
                    domain,
                    "  (:method get-{name}-by-f{s} :parameters (?p ?c) :task (get-{name})\n    :precondition (sig ?p ?c s{s}) :subtasks ({subtasks})\n    :channels ({channels}) :outputs ((({name}) s0)))"
                )
                .ok();
            }
        }
    }
    domain.push_str(
        "  (:task serve :parameters ())\n  (:method serve-user :parameters (?p ?c) :task (serve)\n    :precondition (user ?p ?c) :subtasks ((s0 (user ?p ?c)) (s1 (get-goal)))\n    :channels ((s1 s0 (goal))))\n)",
    );
    let mut instance = finish(domain, facts, "(serve)".to_string(), components)?;
    instance.exclusions = exclusions;
    Ok(instance)
}
