"""The soak's reports: report.json (build, totals, schema, the baseline comparison), report.html
(html, plots; Jinja2 templates in eval/templates/), junit.xml and the console summary.
"""
