"""The soak's reports: report.json (build, totals, schema, the baseline comparison), report.html
(html, plots; Jinja2 templates in sim2real/eval/templates/), junit.xml and the console summary.
"""
