use boucwen_cli::sweep::{self, SweepOptions};
fn main() {
    let args: Vec<f64> = std::env::args().skip(1).map(|a| a.parse().unwrap()).collect();
    let mut o = SweepOptions::paper(args.first().copied().unwrap_or(10.0));
    o.freqs = if args.len() > 1 { args[1..].to_vec() } else { vec![1.0, 5.0, 10.0, 14.0, 15.0, 20.0, 22.0, 23.0, 24.0, 30.0, 40.0, 50.0] };
    let r = sweep::run(&o, &|| {}).unwrap();
    println!("{}", sweep::CSV_HEADER.replace(",", "\t"));
    for row in &r.rows { println!("{}", row.csv().split(',').map(|s| if s.len() > 8 { &s[..8] } else { s }).collect::<Vec<_>>().join("\t")); }
    println!("wall {:.2} s, speed-up {:.0}x", r.wall_s, r.speedup());
}
