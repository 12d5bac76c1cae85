//! `falc report`: the figures of a range as one self-contained HTML page
//! (no script, no link out), each chart an inline SVG drawn with
//! `plotters`: OEE with availability, effectiveness and quality per shift
//! (per day without a shift calendar), a cycle-time histogram per recipe,
//! the alarm Pareto, and a Gantt chart of the last order runs.

use falc_model::figures::{CellFigures, Figures, Percent};
use plotters::prelude::*;
use std::fmt::Write as _;

/// Chart size, pixels.
const W: u32 = 860;
const H: u32 = 300;

/// Bins of a cycle-time histogram.
const BINS: usize = 10;

type Drawn = Result<String, String>;

fn failed<E: std::fmt::Debug>(what: &str) -> impl Fn(E) -> String + '_ {
    move |e| format!("cannot draw {what}: {e:?}")
}

/// `text` safe inside HTML.
fn escape(text: &str) -> String {
    falc_model::ids::printable(text)
        .replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Slots per period in the OEE chart: four bars and a gap.
const OEE_SLOTS: usize = 5;
/// The OEE chart's axis ends here; a longer bar is cut (effectiveness
/// above 100 % means runs faster than planned).
const OEE_TOP: f64 = 150.0;

/// OEE and its three factors per period, as a group of bars each.
fn oee_chart(c: &CellFigures) -> Drawn {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(failed("the OEE chart"))?;
        let n = c.periods.len().max(1);
        type Factor = fn(&falc_model::figures::Period) -> Option<f64>;
        let series: [(&str, RGBColor, Factor); 4] = [
            ("OEE", RGBColor(40, 40, 40), |p| p.oee()),
            ("availability", BLUE, |p| p.availability()),
            ("effectiveness", RGBColor(230, 120, 0), |p| {
                p.effectiveness()
            }),
            ("quality", RGBColor(0, 150, 60), |p| p.quality()),
        ];
        let top = c
            .periods
            .iter()
            .flat_map(|p| series.iter().filter_map(|(_, _, f)| f(p)))
            .fold(1.0_f64, f64::max)
            .min(OEE_TOP / 110.0)
            * 110.0;
        let labels: Vec<String> = c.periods.iter().map(|p| p.label.clone()).collect();
        let mut chart = ChartBuilder::on(&root)
            .caption("OEE and its factors per period (%)", ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(0..n * OEE_SLOTS, 0.0..top)
            .map_err(failed("the OEE chart"))?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(n * OEE_SLOTS + 1)
            .x_label_formatter(&|x| {
                // Under the middle of each group only.
                if x % OEE_SLOTS == 2 {
                    labels.get(x / OEE_SLOTS).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .y_desc("%")
            .draw()
            .map_err(failed("the OEE chart"))?;
        for (k, (name, color, factor)) in series.into_iter().enumerate() {
            let bars = c.periods.iter().enumerate().filter_map(move |(i, p)| {
                let v = (factor(p)? * 100.0).min(top);
                let x0 = i * OEE_SLOTS + k;
                Some(Rectangle::new(
                    [(x0, 0.0), (x0 + 1, v)],
                    color.mix(0.85).filled(),
                ))
            });
            chart
                .draw_series(bars)
                .map_err(failed("the OEE chart"))?
                .label(name)
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 12, y + 5)], color.filled())
                });
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(failed("the OEE chart"))?;
        root.present().map_err(failed("the OEE chart"))?;
    }
    Ok(svg)
}

/// A histogram of one recipe's done run times.
fn cycle_chart(recipe: &str, runs_ms: &[i64]) -> Drawn {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (W / 2, H)).into_drawing_area();
        root.fill(&WHITE)
            .map_err(failed("a cycle-time histogram"))?;
        let secs: Vec<f64> = runs_ms.iter().map(|ms| *ms as f64 / 1000.0).collect();
        let lo = secs.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = secs.iter().copied().fold(0.0_f64, f64::max);
        let (lo, hi) = if secs.is_empty() {
            (0.0, 1.0)
        } else if hi - lo < 1e-9 {
            (lo - 0.5, hi + 0.5)
        } else {
            (lo, hi)
        };
        let width = (hi - lo) / BINS as f64;
        let mut counts = [0u32; BINS];
        for s in &secs {
            let i = (((s - lo) / width) as usize).min(BINS - 1);
            counts[i] += 1;
        }
        let most = counts.iter().copied().max().unwrap_or(1).max(1);
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("cycle time of {recipe} ({} done)", secs.len()),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(40)
            .build_cartesian_2d(lo..hi, 0u32..most + 1)
            .map_err(failed("a cycle-time histogram"))?;
        chart
            .configure_mesh()
            .x_desc("seconds")
            .y_desc("runs")
            .draw()
            .map_err(failed("a cycle-time histogram"))?;
        chart
            .draw_series(counts.iter().enumerate().map(|(i, n)| {
                let x0 = lo + i as f64 * width;
                Rectangle::new([(x0, 0), (x0 + width, *n)], BLUE.mix(0.6).filled())
            }))
            .map_err(failed("a cycle-time histogram"))?;
        root.present().map_err(failed("a cycle-time histogram"))?;
    }
    Ok(svg)
}

/// Slots per line of the Pareto: a gap, the bar, a gap.
const PARETO_SLOTS: usize = 4;

/// The alarm Pareto: down time per station and class, most first, with
/// the cumulative share.
fn pareto_chart(c: &CellFigures) -> Drawn {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(failed("the alarm Pareto"))?;
        let lines: Vec<_> = c.pareto.iter().take(12).collect();
        let n = lines.len().max(1);
        let minutes: Vec<f64> = lines.iter().map(|l| l.ms as f64 / 60_000.0).collect();
        let total: f64 = minutes.iter().sum::<f64>().max(1e-9);
        let most = minutes.iter().copied().fold(0.0_f64, f64::max);
        let most = if most > 0.0 { most } else { 1e-3 };
        let top = most * 1.15;
        let labels: Vec<String> = lines
            .iter()
            .map(|l| format!("{} {} ({})", l.station, l.class, l.count))
            .collect();
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "alarms: down time per station and class",
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0..n * PARETO_SLOTS, 0.0..top)
            .map_err(failed("the alarm Pareto"))?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(n * PARETO_SLOTS + 1)
            .x_label_formatter(&|x| {
                if x % PARETO_SLOTS == 2 {
                    labels.get(x / PARETO_SLOTS).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .y_desc("minutes")
            .draw()
            .map_err(failed("the alarm Pareto"))?;
        chart
            .draw_series(minutes.iter().enumerate().map(|(i, m)| {
                let x0 = i * PARETO_SLOTS + 1;
                Rectangle::new([(x0, 0.0), (x0 + 2, *m)], RED.mix(0.6).filled())
            }))
            .map_err(failed("the alarm Pareto"))?;
        // The cumulative share: 100 % at the highest bar's height.
        let mut sum = 0.0;
        let cumulative: Vec<(usize, f64)> = minutes
            .iter()
            .enumerate()
            .map(|(i, m)| {
                sum += m;
                (i * PARETO_SLOTS + 2, sum / total * most)
            })
            .collect();
        chart
            .draw_series(LineSeries::new(cumulative.clone(), BLACK.stroke_width(1)))
            .map_err(failed("the alarm Pareto"))?;
        chart
            .draw_series(
                cumulative
                    .iter()
                    .map(|p| Circle::new(*p, 3, BLACK.filled())),
            )
            .map_err(failed("the alarm Pareto"))?;
        root.present().map_err(failed("the alarm Pareto"))?;
    }
    Ok(svg)
}

/// The last order runs as bars in time, coloured by how they ended.
fn gantt_chart(c: &CellFigures) -> Drawn {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (W, H / 2 + 60)).into_drawing_area();
        root.fill(&WHITE).map_err(failed("the Gantt chart"))?;
        let start = c.runs.first().map_or(0, |r| r.start_ms);
        let end = c.runs.iter().map(|r| r.end_ms).max().unwrap_or(start + 1);
        let minutes = |ms: i64| (ms - start) as f64 / 60_000.0;
        let span = minutes(end).max(1e-3);
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("the last {} order runs of {}", c.runs.len(), c.cell),
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..span, 0.0..1.0)
            .map_err(failed("the Gantt chart"))?;
        chart
            .configure_mesh()
            .disable_y_mesh()
            .y_labels(0)
            .x_desc(format!("minutes from {}", crate::clock::date_time(start)))
            .draw()
            .map_err(failed("the Gantt chart"))?;
        chart
            .draw_series(c.runs.iter().map(|r| {
                let color = match r.state.as_str() {
                    "done" => RGBColor(0, 150, 60),
                    "failed" => RED,
                    "running" => BLUE,
                    _ => RGBColor(150, 150, 150),
                };
                Rectangle::new(
                    [(minutes(r.start_ms), 0.25), (minutes(r.end_ms), 0.75)],
                    color.mix(0.8).filled(),
                )
            }))
            .map_err(failed("the Gantt chart"))?;
        root.present().map_err(failed("the Gantt chart"))?;
    }
    Ok(svg)
}

/// One chart in its figure.
fn figure(out: &mut String, id: &str, caption: &str, svg: &str) {
    let _ = writeln!(
        out,
        "<figure id=\"{id}\">{svg}<figcaption>{}</figcaption></figure>",
        escape(caption)
    );
}

/// The report as one HTML page.
pub fn html(f: &Figures) -> Result<String, String> {
    let range = format!(
        "{} to {}",
        crate::clock::date_time(f.since_ms),
        crate::clock::date_time(f.until_ms)
    );
    let mut out = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>FALC report {}</title>\
         <style>body{{font-family:sans-serif;margin:2em;max-width:900px}}\
         table{{border-collapse:collapse}}td,th{{border:1px solid #aaa;padding:2px 8px;text-align:right}}\
         figure{{margin:1em 0}}figcaption{{color:#444}}</style></head><body>\n\
         <h1>FALC: what the cell made, and how well</h1><p>{}; figures by ISO 22400-2.</p>\n",
        escape(&range),
        escape(&range)
    );
    for c in &f.cells {
        let t = &c.total;
        let _ = writeln!(
            out,
            "<h2>cell {}</h2><table><tr><th>availability</th><th>effectiveness</th>\
             <th>quality</th><th>OEE</th><th>made</th><th>good</th></tr>\
             <tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr></table>",
            escape(&c.cell),
            Percent(t.availability()),
            Percent(t.effectiveness()),
            Percent(t.quality()),
            Percent(t.oee()),
            t.quantities.produced,
            t.quantities.good
        );
        let id = |what: &str| format!("{what}-{}", escape(&c.cell));
        figure(
            &mut out,
            &id("oee"),
            "OEE = availability × effectiveness × quality, per shift (per day without a shift calendar); bars are cut at 150 %",
            &oee_chart(c)?,
        );
        for ct in &c.cycle {
            figure(
                &mut out,
                &format!("{}-{}", id("cycle"), escape(&ct.recipe)),
                &format!(
                    "cycle time of {}: p50 {:.1} s, p95 {:.1} s",
                    ct.recipe,
                    ct.p50_ms as f64 / 1000.0,
                    ct.p95_ms as f64 / 1000.0
                ),
                &cycle_chart(&ct.recipe, &ct.runs_ms)?,
            );
        }
        figure(
            &mut out,
            &id("pareto"),
            "alarms per station and class (count in brackets), most down time first; the line is the cumulative share (100 % at the highest bar)",
            &pareto_chart(c)?,
        );
        figure(
            &mut out,
            &id("gantt"),
            "order runs: green done, red failed, grey stopped or interrupted, blue running",
            &gantt_chart(c)?,
        );
    }
    out.push_str("</body></html>\n");
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_factory::figures::{compute, AlarmSpan, FigureInputs, RunSpan};
    use falc_model::alarm::AlarmClass;
    use falc_model::calendar::Calendar;
    use falc_model::figures::FigureQuery;
    use falc_model::records::OrderState;

    #[test]
    fn the_report_holds_its_four_charts_as_inline_svg() {
        let run = |order, start, end, state| RunSpan {
            order,
            recipe: "dikdroog".into(),
            cell: "falc1".into(),
            start_ms: start,
            end_ms: Some(end),
            state,
        };
        let inputs = FigureInputs {
            runs: (0..8)
                .map(|i| {
                    let state = if i == 3 {
                        OrderState::Failed
                    } else {
                        OrderState::Done
                    };
                    run(i, i * 100_000, i * 100_000 + 60_000 + i * 1000, state)
                })
                .collect(),
            alarms: vec![AlarmSpan {
                cell: "falc1".into(),
                station: "welding".into(),
                class: AlarmClass::Safety,
                raised_ms: 361_000,
                gone_ms: Some(390_000),
            }],
            modes: Vec::new(),
            // The list worked all along (no shift calendar: planned).
            lists: vec![falc_factory::figures::ListChange {
                cell: "falc1".into(),
                at_ms: 0,
                working: true,
            }],
        };
        let query = FigureQuery {
            since_ms: 0,
            until_ms: Some(900_000),
            planned: Vec::new(),
        };
        let f = compute(&inputs, &Calendar::default(), &["falc1"], &query, 900_000);
        let page = html(&f).expect("drawn");
        for id in [
            "oee-falc1",
            "cycle-falc1-dikdroog",
            "pareto-falc1",
            "gantt-falc1",
        ] {
            assert!(
                page.contains(&format!("<figure id=\"{id}\"><svg")),
                "no {id}"
            );
        }
        assert_eq!(page.matches("<svg").count(), 4);
        assert_eq!(page.matches("</svg>").count(), 4);
        // Bars: 8 runs in the Gantt chart, and the histogram's bins.
        assert!(page.matches("<rect").count() >= 8 + BINS);
        assert!(!page.contains("<script"));
        assert!(page.contains("87.5%"), "quality 7 of 8");
    }
}
